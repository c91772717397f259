"""scripts/evaluate_learned_stages.py on one held-out frame: the tables it prints, and the bound of
the input scale (the reference labels pooled and repeated back) near perfect for the elements."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from histostudy.learning import shipped_model

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "evaluate_learned_stages.py"


@pytest.mark.skipif(shipped_model("unet_standard") is None or shipped_model("vgg19_standard") is None,
                    reason="the shipped networks are missing")
def test_one_held_out_frame_is_measured_by_both_stages(tmp_path):
    env = {**os.environ, "HISTOSTUDY_CACHE": str(tmp_path)}
    done = subprocess.run([sys.executable, str(SCRIPT), "--seed", "5", "--frames", "1", "--workers", "1"],
                          capture_output=True, text=True, timeout=600, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    out = done.stdout
    assert "1 frames of split 'eval', seed 5" in out
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| (\w+) \| (.+) \|$", out, re.M)}
    assert {"transducer", "outer_boundary", "inner_boundary", "gaps", "screws"} <= set(rows)
    bound_iou = float(rows["transducer"].split("|")[-1].split("/")[0])
    assert bound_iou > 95.0  # pooling to 0.5 and back loses only the elements' rim
    assert "conic (pipeline)" in out and "VGG19 alone" in out
    assert list(tmp_path.rglob("eval-5-000000.npz"))  # the frame went to the cache it was given
