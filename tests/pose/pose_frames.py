"""Synthetic biplane frames with known truth, shared by the pose tests (tests/test_pose_*.py).

Frames carry reference labels rendered from a fine digital model; the image content does not enter
the pose, so it is left blank for speed.
"""

import numpy as np

from histostudy.imaging import Frame, default_biplane, render_labels
from histostudy.transducer import pose_facing

POSES = [
    pose_facing((0.15, 1.0, 0.25), focal_point_mm=(4.0, -6.0, 8.0), axial_rotation_rad=0.35),
    pose_facing((-0.3, 1.0, -0.1), focal_point_mm=(-10.0, 5.0, -3.0), axial_rotation_rad=2.0),
]


def frames_of(fine, T, views=None, labels_pose=None):
    """One blank-image frame per view (default: the biplane pair) with the labels of ``fine`` at
    ``T``, or at ``labels_pose[i]`` for view ``i`` where given (contradicting views)."""
    views = default_biplane() if views is None else views
    out = []
    for i, v in enumerate(views):
        T_labels = T if labels_pose is None or labels_pose[i] is None else labels_pose[i]
        out.append(Frame(np.zeros(v.shape, np.float32), v, labels=render_labels(fine, T_labels, v),
                         T_carm_transducer=T))
    return out


def focal_error(result, T):
    """Distance (mm) of an estimate's focal point from ``T``'s (the transducer frame's origin)."""
    return float(np.linalg.norm(result.focal_point_mm - T[:3, 3]))


def moved(T, step):
    """``T`` moved by ``step`` (a transform in the C-arm frame, about the focal point)."""
    out = T.copy()
    out[:3, :3] = step[:3, :3] @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + step[:3, 3]
    return out


def assert_jump_reacquired(tracker, fine, views, T_before, T_jump, T_after):
    """Track ``T_before``, then a jump to ``T_jump``: the warm start is lost, the same frames are
    re-acquired from scratch (focal point within 0.1 mm), and ``T_after`` is tracked warm again."""
    tracker.update(frames_of(fine, T_before, views))
    result = tracker.update(frames_of(fine, T_jump, views))
    assert tracker.last_kind == "reacquired" and result.verdict.ok and result.init is not None
    assert focal_error(result, T_jump) < 0.1
    assert (tracker.n_lost, tracker.n_reacquired, tracker.n_from_scratch) == (1, 1, 2)
    tracker.update(frames_of(fine, T_after, views))
    assert tracker.last_kind == "warm" and tracker.n_warm == 1 and tracker.n_accepted == 3
