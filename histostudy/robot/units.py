"""The unit boundary between the library and ur_rtde (§II-C): ur_rtde's metres and axis-angle poses
``[x, y, z, rx, ry, rz]`` against the library's millimetres and 4x4 transforms ``T_<to>_<from>``,
converted here and nowhere else (the RTDE client and the simulated controller both use it)."""

from __future__ import annotations

import numpy as np

from histostudy.geometry import check_rigid, matrix_from_rotvec, rotvec_from_matrix

__all__ = ["pose_from_transform", "transform_from_pose"]


def pose_from_transform(T) -> list[float]:
    """The ur_rtde pose of a rigid transform.

    Args:
        T: (4, 4) rigid transform ``T_<to>_<from>``, translation in mm (e.g. ``T_base_tcp``).

    Returns:
        ``[x, y, z, rx, ry, rz]``: the translation in metres and the rotation as an axis-angle
        vector in rad, as Python floats.

    Raises:
        ValueError: ``T`` is not a finite (4, 4) rigid transform.
    """
    T = check_rigid(T, "T")
    return [float(v) for v in np.concatenate([T[:3, 3] / 1000.0, rotvec_from_matrix(T[:3, :3])])]


def transform_from_pose(pose, name: str = "pose") -> np.ndarray:
    """The rigid transform of a ur_rtde pose.

    Args:
        pose: ``[x, y, z, rx, ry, rz]``: translation in metres, axis-angle rotation in rad.
        name: what the error message calls ``pose``.

    Returns:
        (4, 4) float64 rigid transform, translation in mm.

    Raises:
        ValueError: ``pose`` is not 6 finite numbers.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(-1)
    if p.shape != (6,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be 6 finite numbers [x, y, z (m), rx, ry, rz (rad)], got {pose!r}")
    T = np.eye(4)
    T[:3, :3] = matrix_from_rotvec(p[3:])
    T[:3, 3] = p[:3] * 1000.0
    return T
