"""scripts/tracking_by_network.py's cine moves as tests/lab/test_receiver.py's does: each pose about
0.9 mm and 0.9 deg from the last."""

import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "tracking_by_network.py"


def test_the_cine_steps_about_a_millimetre_and_a_degree():
    spec = importlib.util.spec_from_file_location("tracking_by_network", SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    poses = script.moving_poses(4)
    assert len(poses) == 4
    for a, b in zip(poses, poses[1:]):
        angle = np.degrees(np.arccos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1)))
        assert 0.8 < np.linalg.norm(b[:3, 3] - a[:3, 3]) < 1.0 and 0.8 < angle < 1.0
