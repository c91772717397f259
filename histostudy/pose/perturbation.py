"""The pose parameterisation of the refinement (§II-B.3): the left perturbation about the focal point,
``R' = exp([w]x) R``, ``t' = t + v`` (``w`` in rad, ``v`` in mm, C-arm frame), and the
Gauss-Newton normal equations taken with it (docs/pose-estimation.md, "The left perturbation").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NormalEquations", "apply_left_perturbation"]


@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton quantities at one pose (left perturbation ``[w (rad), v (mm)]`` about the focal point).

    ``cost`` = C (eq. 3) = ``sum r²``; ``JtJ`` (6, 6) and ``Jtr`` (6,) with ``J = dr/d[w, v]``.
    The gradient of C is ``2 Jtr``.
    """

    cost: float
    JtJ: np.ndarray
    Jtr: np.ndarray


def apply_left_perturbation(T, delta) -> np.ndarray:
    """The pose after a left perturbation about the focal point (§II-B.3): ``R' = exp([w]x) R``, ``t' = t + v``.

    The rotation turns the transducer about its own origin (the focal point) in world axes, so
    rotation and translation steps do not mix; this is the perturbation the Jacobians of
    :class:`~.cost.PoseCost` are taken with, and Levenberg-Marquardt's step.

    Args:
        T: a 4x4 pose ``T_carm_transducer`` (mm).
        delta: 6 numbers ``[w (rad), v (mm)]``, both in the C-arm frame.

    Returns:
        The perturbed 4x4 pose ``T_carm_transducer``.

    Raises:
        ValueError: ``delta`` is not 6 finite numbers.
    """
    T = np.asarray(T, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64).reshape(-1)
    if d.shape != (6,) or not np.isfinite(d).all():
        raise ValueError(f"delta must be 6 finite numbers [w (rad), v (mm)], got {delta!r}")
    out = np.eye(4)
    out[:3, :3] = _matrix_from_rotvec(*d[:3].tolist()) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + d[3:]
    return out


def _matrix_from_rotvec(x: float, y: float, z: float) -> np.ndarray:
    """:func:`~histostudy.geometry.matrix_from_rotvec` of the rotation vector ``(x, y, z)`` (rad) in
    scalar arithmetic: SciPy's own route (the unit quaternion of the rotation vector, with its series
    for angles <= 1e-3 rad, then the quaternion's matrix), equal to it up to float rounding, without
    the time SciPy spends per call on its checks and array set-up (one call per Levenberg-Marquardt
    step; docs/tracking.md)."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:
        a2 = angle * angle
        scale = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        scale = math.sin(angle / 2.0) / angle
    qx, qy, qz, qw = x * scale, y * scale, z * scale, math.cos(angle / 2.0)
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    xx, yy, zz, ww = qx * qx, qy * qy, qz * qz, qw * qw
    xy, zw, xz, yw, yz, xw = qx * qy, qz * qw, qx * qz, qy * qw, qy * qz, qx * qw
    return np.array([[xx - yy - zz + ww, 2.0 * (xy - zw), 2.0 * (xz + yw)],
                     [2.0 * (xy + zw), -xx + yy - zz + ww, 2.0 * (yz - xw)],
                     [2.0 * (xz - yw), 2.0 * (yz + xw), -xx - yy + zz + ww]])
