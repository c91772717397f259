"""The prepared GPU run (scripts/gpu_training_run.py), end to end on the CPU at toy size: what the
next lent GPU runs at full size, its outputs as the device tool brings them back."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "gpu_training_run.py"


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA machine runs the script at full size instead")
def test_the_gpu_run_renders_trains_exports_and_evaluates_at_toy_size(tmp_path):
    out, cache = tmp_path / "out", tmp_path / "cache"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    done = subprocess.run([sys.executable, str(SCRIPT), "--out", str(out), "--eval-seed", "777", "--toy",
                           "--render-workers", "2", "--cache-dir", str(cache)],
                          capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    files = sorted(p.name for p in out.iterdir())
    assert files == ["run.json", "unet_gpu.json", "unet_gpu.safetensors", "vgg19_gpu.json", "vgg19_gpu.safetensors"]
    # the device tool brings back at most 8 files of 16 MiB
    assert len(files) + 1 <= 8 and all((out / f).stat().st_size <= 16 * 2**20 for f in files)
    run = json.loads((out / "run.json").read_text())
    assert run["toy"] and run["eval_seed"] == 777 and run["device"] == "cpu" and "CPU:" in run["machine"]
    for name, arch in (("segmentation_gpu", "unet"), ("orientation_gpu", "vgg19")):
        table = run["tables"][name]
        assert table["steps"] >= 1 and table["weights"] == f"{arch}_gpu.safetensors"
        assert set(table["evaluation"]) == {"trained", "shipped", "frames"}
        manifest = json.loads((out / f"{arch}_gpu.json").read_text())
        assert set(manifest["tensor_dtypes"].values()) <= {"float16", "int64"}
        assert manifest["float16_of"] and manifest["profile"] == "standard"
    seg = run["tables"]["segmentation_gpu"]["evaluation"]["trained"]
    assert 0 <= seg["global_accuracy_percent"] <= 100 and "screws" in seg["per_class_percent"]
    ori = run["tables"]["orientation_gpu"]["evaluation"]["trained"]
    assert 0 <= ori["azimuth_mae_deg"] <= 180 and 0 <= ori["elevation_mae_deg"] <= 180


def test_the_gpu_run_refuses_to_run_full_size_without_cuda(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    done = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path), "--eval-seed", "1"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "no CUDA device" in done.stderr
    assert not (tmp_path / "run.json").exists()
