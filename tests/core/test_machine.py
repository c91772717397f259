"""Tests of histostudy.core.machine: the CPU's flags as torch's own detection sees them, the
restriction read from the environment, and native bfloat16 off under it."""

import os
import subprocess
import sys

import pytest
import torch

from histostudy.core import avx2_env_words, avx2_restriction, machine_summary, run_restricted_to
from histostudy.core.machine import AVX2_RESTRICTION, ISA_RESTRICTION_ENV, isa_flags, isa_restriction

linux = pytest.mark.skipif(not os.path.exists("/proc/cpuinfo"), reason="no /proc/cpuinfo on this system")


@linux
def test_flags_agree_with_torchs_cpu_detection():
    flags = isa_flags()
    assert flags["avx512_bf16"] == torch.cpu._is_avx512_bf16_supported()  # torch asks cpuinfo's CPUID itself
    assert flags["amx_tile"] == torch.cpu._is_amx_tile_supported()
    assert flags["avx2"] == torch.cpu._is_avx2_supported()
    assert not flags["avx512_bf16"] or flags["avx512f"]  # BF16 is an AVX-512 extension


def test_restriction_is_read_from_the_environment(monkeypatch):
    for name in ISA_RESTRICTION_ENV:
        monkeypatch.delenv(name, raising=False)
    assert isa_restriction() == {}
    assert "ISA restriction: none" in machine_summary()
    for name, value in avx2_restriction().items():
        monkeypatch.setenv(name, value)
    assert isa_restriction() == avx2_restriction()
    summary = machine_summary()
    assert "ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 NUMBA_CPU_NAME=haswell" in summary
    assert len(summary.splitlines()) == 3 and "torch 2." in summary


def test_the_avx2_restriction_turns_numpys_avx512_loops_off_and_make_sets_it(tmp_path):
    from pathlib import Path

    restriction = avx2_restriction()
    assert restriction.items() >= AVX2_RESTRICTION.items()
    env = {k: v for k, v in os.environ.items() if k not in ISA_RESTRICTION_ENV} | restriction
    code = ("import numpy; from numpy._core._multiarray_umath import __cpu_features__ as f; "
            "print(f.get('X86_V4', False) or f.get('AVX512_ICL', False))")
    out = subprocess.run([sys.executable, "-W", "error", "-c", code], env=env, capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False" and out.stderr == ""
    # what make puts before the suite (dry run: prints the command, runs nothing)
    root = Path(__file__).parents[2]
    if not (root / ".venv" / "bin" / "python").exists():
        pytest.skip("no .venv here: make's restriction is computed by the project's virtualenv")
    dry = subprocess.run(["make", "-n", "-o", ".venv/.histostudy-installed", "test-avx2"], cwd=root,
                         capture_output=True, text=True, check=True).stdout
    assert avx2_env_words() in dry and "-m pytest" in dry


def _native_bfloat16_in_a_fresh_interpreter(**restriction) -> bool:
    """native_bfloat16() in a new process with only ``restriction`` set (ATen reads its capability
    once, at its first dispatch)."""
    code = "from histostudy.learning import native_bfloat16; print(native_bfloat16())"
    env = {k: v for k, v in os.environ.items() if k not in ISA_RESTRICTION_ENV} | restriction
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return {"True": True, "False": False}[out.stdout.strip()]


def test_native_bfloat16_follows_the_cpu_and_is_off_below_avx512():
    expected = torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
    assert _native_bfloat16_in_a_fresh_interpreter() == bool(expected)
    assert _native_bfloat16_in_a_fresh_interpreter(ATEN_CPU_CAPABILITY="avx2") is False


@pytest.mark.parametrize("value", ["AVX2", "avx512_core", "AVX512_CORE_VNNI"])
def test_native_bfloat16_is_off_when_onednn_is_held_below_its_bfloat16_kernels(monkeypatch, value):
    from histostudy.learning import native_bfloat16

    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", value)
    assert native_bfloat16() is False


def test_run_restricted_to_avx2_reruns_the_command_as_an_avx2_cpu(tmp_path):
    """A benchmark's --isa avx2: the same command again, its libraries held to AVX2 (torch's kernel
    level says so, bfloat16 is off); 'native' changes nothing; another name is refused."""
    script = tmp_path / "probe.py"
    script.write_text("import sys, torch\n"
                      "from histostudy.core.machine import isa_restriction, run_restricted_to\n"
                      "from histostudy.learning import native_bfloat16\n"
                      "run_restricted_to(sys.argv[1])\n"
                      "print(sys.argv[1:], torch.backends.cpu.get_cpu_capability(), native_bfloat16(),\n"
                      "      sorted(isa_restriction()))\n")
    env = {k: v for k, v in os.environ.items() if k not in ISA_RESTRICTION_ENV}
    out = subprocess.run([sys.executable, str(script), "avx2", "extra"], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == f"['avx2', 'extra'] AVX2 False {sorted(avx2_restriction())}"
    native = subprocess.run([sys.executable, str(script), "native"], env=env, capture_output=True, text=True,
                            check=True).stdout
    assert native.endswith("[]\n")  # no restriction set, none added
    with pytest.raises(ValueError, match=r"isa must be one of \('native', 'avx2'\), got 'sse'"):
        run_restricted_to("sse")
