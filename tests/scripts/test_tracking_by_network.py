"""scripts/tracking_by_network.py's cine moves as tests/lab/test_receiver.py's does: each pose about
0.9 mm and 0.9 deg from the last."""

import numpy as np


def test_the_cine_steps_about_a_millimetre_and_a_degree(load_script):
    poses = load_script("tracking_by_network").moving_poses(4)
    assert len(poses) == 4
    for a, b in zip(poses, poses[1:]):
        angle = np.degrees(np.arccos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1)))
        assert 0.8 < np.linalg.norm(b[:3, 3] - a[:3, 3]) < 1.0 and 0.8 < angle < 1.0
