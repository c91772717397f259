"""The unit boundary between the library and ur_rtde (§II-C robot layer): ur_rtde speaks metres and
axis-angle poses ``[x, y, z, rx, ry, rz]``, the library millimetres and 4x4 transforms
``T_<to>_<from>`` (docs/architecture.md, Frames and units). These two functions convert, here
and nowhere else: :class:`~histostudy.robot.rtde._robot.RTDERobot` on the client side and the simulated
controller (``controller_arm``, ``controller_program``) on the other.
"""

from __future__ import annotations

import numpy as np

from histostudy.geometry import check_rigid, matrix_from_rotvec, rotvec_from_matrix

__all__ = ["pose_from_transform", "transform_from_pose"]


def pose_from_transform(T) -> list[float]:
    """ur_rtde pose ``[x, y, z, rx, ry, rz]`` (m, axis-angle rad) of a 4x4 transform in mm."""
    T = check_rigid(T, "T")
    return [float(v) for v in np.concatenate([T[:3, 3] / 1000.0, rotvec_from_matrix(T[:3, :3])])]


def transform_from_pose(pose, name: str = "pose") -> np.ndarray:
    """4x4 transform in mm of a ur_rtde pose ``[x, y, z, rx, ry, rz]`` (m, axis-angle rad)."""
    p = np.asarray(pose, dtype=np.float64).reshape(-1)
    if p.shape != (6,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be 6 finite numbers [x, y, z (m), rx, ry, rz (rad)], got {pose!r}")
    T = np.eye(4)
    T[:3, :3] = matrix_from_rotvec(p[3:])
    T[:3, 3] = p[:3] * 1000.0
    return T
