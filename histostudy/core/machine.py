"""Which CPU a run had, and which of its instruction sets the numerical libraries were allowed to
use (docs/testing.md, "Every CPU"): the line a benchmark, a test session and CI print first, part of
every result's provenance, and the environment that holds the libraries to AVX2 (``make test-avx2``).
"""

from __future__ import annotations

import functools
import os
import platform
from importlib import metadata

__all__ = ["AVX2_RESTRICTION", "BENCHMARK_ISAS", "ISA_FLAGS", "ISA_RESTRICTION_ENV", "avx2_env_words",
           "avx2_restriction", "cpu_model", "isa_flags", "isa_restriction", "machine_summary", "run_restricted_to"]

#: The CPU flags (as Linux's /proc/cpuinfo names them) that decide which kernels run here.
ISA_FLAGS = ("avx2", "fma", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16")

#: The environment variables that hold the libraries below the CPU's instruction set: oneDNN
#: (torch's convolutions), ATen (torch's other kernels), numba (this project's compiled kernels) and
#: numpy (its run-time dispatched loops).
ISA_RESTRICTION_ENV = ("ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY", "NUMBA_CPU_NAME", "NPY_DISABLE_CPU_FEATURES")

#: The restriction of torch and numba that makes any x86-64 machine compute as an AVX2-only CPU (a
#: Haswell) would; :func:`avx2_restriction` adds numpy's.
AVX2_RESTRICTION = {"ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2", "NUMBA_CPU_NAME": "haswell"}

#: What a benchmark's ``--isa`` takes (:func:`run_restricted_to`): the CPU as it is, or AVX2 only.
BENCHMARK_ISAS = ("native", "avx2")

_LIBRARIES = ("numpy", "scipy", "numba", "torch", "opencv-python-headless")


@functools.lru_cache(maxsize=1)
def _cpuinfo() -> dict[str, str]:
    """The first processor's entries of /proc/cpuinfo ({} where there is none); read once, as the
    CPU does not change under a running process (callers only read the dict)."""
    entries: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                if not line.strip():
                    if entries:
                        break
                    continue
                key, _, value = line.partition(":")
                entries.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    return entries


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string elsewhere."""
    return _cpuinfo().get("model name") or platform.processor() or platform.machine()


def isa_flags() -> dict[str, bool]:
    """Whether the CPU has each of :data:`ISA_FLAGS` (all False where /proc/cpuinfo is missing)."""
    flags = set(_cpuinfo().get("flags", "").split())
    return {name: name in flags for name in ISA_FLAGS}


def avx2_restriction() -> dict[str, str]:
    """The environment that makes the libraries compute as on an AVX2-only CPU (a Haswell).

    The numbers depend on the instruction set through the order in which oneDNN and torch sum a
    convolution's products (float32 rounding); these variables hold the libraries below the CPU's
    own (:data:`ISA_RESTRICTION_ENV`) so that one machine reproduces another's case.

    Returns:
        :data:`AVX2_RESTRICTION` plus ``NPY_DISABLE_CPU_FEATURES``: the installed numpy's dispatch
        targets beyond AVX2 (their names change between numpy versions, and naming one it lacks
        makes numpy warn at import), as ``{variable: value}``.
    """
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__  # type: ignore[no-redef]
    beyond_avx2 = [name for name in __cpu_dispatch__ if "512" in name or name == "X86_V4"]
    return AVX2_RESTRICTION | ({"NPY_DISABLE_CPU_FEATURES": " ".join(beyond_avx2)} if beyond_avx2 else {})


def avx2_env_words() -> str:
    """:func:`avx2_restriction` for a shell.

    Returns:
        Shell words ``VAR=value ...`` (values quoted), as ``make test-avx2`` puts them before its
        command.
    """
    import shlex

    return " ".join(f"{name}={shlex.quote(value)}" for name, value in avx2_restriction().items())


def isa_restriction() -> dict[str, str]:
    """The variables of :data:`ISA_RESTRICTION_ENV` set in this process, with their values."""
    return {name: os.environ[name] for name in ISA_RESTRICTION_ENV if os.environ.get(name)}


def machine_summary() -> str:
    """The machine a benchmark or a test session ran on, as it prints it first.

    Returns:
        Three lines: the CPU (model, cores, ISA flags), the restriction in force (or "none"), and
        the numerical libraries' versions with torch's kernel level (torch imported only if
        installed).
    """
    flags = " ".join(f"{name}={'yes' if present else 'no'}" for name, present in isa_flags().items())
    restriction = " ".join(f"{k}={v}" for k, v in isa_restriction().items()) or "none"
    # provenance.package_versions' loop, which cannot be imported here: provenance imports this module
    versions = [f"python {platform.python_version()}"]
    for name in _LIBRARIES:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{name} not installed")
    try:
        import torch

        versions.append(f"torch kernels {torch.backends.cpu.get_cpu_capability()}")
    except ImportError:
        pass
    return (f"CPU: {cpu_model()}, {os.cpu_count()} cores; {flags}\n"
            f"ISA restriction: {restriction}\n"
            f"libraries: {', '.join(versions)}")


def run_restricted_to(isa: str, argv: list[str] | None = None) -> None:
    """Make this process compute as a CPU of instruction set ``isa`` would (a benchmark's ``--isa``).

    With ``"avx2"``, unless :func:`avx2_restriction`'s variables already hold their values, the
    process is replaced by the same command with them in its environment (oneDNN, ATen and numba
    read them once, when first loaded); it then prints the same results as on an AVX2-only CPU.

    Args:
        isa: ``"native"`` (nothing done) or ``"avx2"`` (:data:`BENCHMARK_ISAS`).
        argv: the command to run again (by ``sys.executable``); default ``sys.argv``.

    Returns:
        None; does not return when it re-executes.

    Raises:
        ValueError: another ``isa``.
    """
    import sys

    if isa not in BENCHMARK_ISAS:
        raise ValueError(f"isa must be one of {BENCHMARK_ISAS}, got {isa!r}")
    if isa == "native":
        return
    wanted = avx2_restriction()
    if all(os.environ.get(name) == value for name, value in wanted.items()):
        return
    argv = list(sys.argv if argv is None else argv)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *argv], {**os.environ, **wanted})
