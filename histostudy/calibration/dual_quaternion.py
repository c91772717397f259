"""Dual quaternions of rigid transforms (§II-C, eq. 8's unknowns and motions), single and batched:
``[q, q']`` with ``q`` the rotation's scalar-first quaternion and ``q' = ½ (0, t) q`` (t in mm);
the batched helpers take ``(n, 4)``, ``(n, 8)`` and ``(n, 4, 4)`` arrays.
"""

from __future__ import annotations

import numpy as np

from histostudy.geometry import check_rigid

__all__ = ["dual_quaternion_from_transform", "transform_from_dual_quaternion"]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
            u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
            u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0],
        ],
        axis=-1,
    )


def quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-first quaternions ``[w, x, y, z]`` (broadcast over leading axes)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    return np.concatenate([pw * qw - np.sum(pv * qv, axis=-1, keepdims=True), pw * qv + qw * pv + _cross(pv, qv)],
                          axis=-1)


def quaternion_conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rotation_angles_rad(R: np.ndarray):
    """Rotation angle (rad, [0, pi]) of (..., 3, 3) rotations, accurate near 0 too (atan2 of sin
    and cos; ``arccos`` of the trace loses half the digits for small residuals)."""
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    out = np.arctan2(0.5 * np.linalg.norm(v, axis=-1), 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0))
    return float(out) if np.ndim(out) == 0 else out


def skew_matrices(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` of (..., 3) vectors: ``skew_matrices(v) @ u == np.cross(v, u)``."""
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], axis=-1),
            np.stack([v[..., 2], z, -v[..., 0]], axis=-1),
            np.stack([-v[..., 1], v[..., 0], z], axis=-1),
        ],
        axis=-2,
    )


def quaternions_from_matrices(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[w, x, y, z]``, ``w >= 0``, of (n, 3, 3) rotations (Bar-Itzhack 2000:
    the eigenvector of the largest eigenvalue of a symmetric 4x4 matrix; exact rotations give
    eigenvalues 1, -1/3, -1/3, -1/3, well separated, so the eigenvector is accurate to rounding)."""
    r = lambda i, j: R[:, i, j]  # noqa: E731
    K = np.empty((len(R), 4, 4))
    K[:, 0, 0] = r(0, 0) + r(1, 1) + r(2, 2)
    K[:, 1, 1] = r(0, 0) - r(1, 1) - r(2, 2)
    K[:, 2, 2] = r(1, 1) - r(0, 0) - r(2, 2)
    K[:, 3, 3] = r(2, 2) - r(0, 0) - r(1, 1)
    K[:, 0, 1] = K[:, 1, 0] = r(2, 1) - r(1, 2)
    K[:, 0, 2] = K[:, 2, 0] = r(0, 2) - r(2, 0)
    K[:, 0, 3] = K[:, 3, 0] = r(1, 0) - r(0, 1)
    K[:, 1, 2] = K[:, 2, 1] = r(0, 1) + r(1, 0)
    K[:, 1, 3] = K[:, 3, 1] = r(0, 2) + r(2, 0)
    K[:, 2, 3] = K[:, 3, 2] = r(1, 2) + r(2, 1)
    _, V = np.linalg.eigh(K / 3.0)
    q = V[:, :, -1]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q


def matrices_from_quaternions(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations of (n, 4) unit quaternions ``[w, x, y, z]``."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def dual_quaternions_from_transforms(T: np.ndarray) -> np.ndarray:
    """(n, 8) unit dual quaternions ``[q, q']`` (``q[0] >= 0``, ``q' = ½ (0, t) q``) of (n, 4, 4)."""
    q = quaternions_from_matrices(T[:, :3, :3])
    t = np.concatenate([np.zeros((len(T), 1)), T[:, :3, 3]], axis=1)
    return np.concatenate([q, 0.5 * quaternion_product(t, q)], axis=1)


def transforms_from_dual_quaternions(dq: np.ndarray) -> np.ndarray:
    """(n, 4, 4) transforms of (n, 8) dual quaternions (real part normalised; t = 2 q' q*)."""
    norm = np.linalg.norm(dq[:, :4], axis=1, keepdims=True)
    q, qd = dq[:, :4] / norm, dq[:, 4:] / norm
    T = np.zeros((len(dq), 4, 4))
    T[:, :3, :3] = matrices_from_quaternions(q)
    T[:, :3, 3] = 2.0 * quaternion_product(qd, quaternion_conjugate(q))[:, 1:]
    T[:, 3, 3] = 1.0
    return T


def invert_transforms(T: np.ndarray) -> np.ndarray:
    """Inverses of (n, 4, 4) rigid transforms (``R.T, -R.T t``)."""
    inv = np.zeros_like(T)
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    inv[:, :3, :3] = Rt
    inv[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    inv[:, 3, 3] = 1.0
    return inv


def dual_quaternion_from_transform(T, name: str = "T") -> np.ndarray:
    """Unit dual quaternion ``[q (4), q' (4)]`` of a rigid transform (translation in mm).

    ``q`` is the rotation's quaternion, scalar first with ``q[0] >= 0``; ``q' = ½ (0, t) q``.
    Dual-quaternion products compose like the matrices: ``dq(T1 @ T2) = dq(T1) dq(T2)`` up to sign.
    """
    return dual_quaternions_from_transforms(check_rigid(T, name)[None])[0]


def transform_from_dual_quaternion(dq) -> np.ndarray:
    """4x4 transform of a dual quaternion ``[q, q']`` (``q`` normalised here; t = 2 q' q*)."""
    dq = np.asarray(dq, dtype=np.float64).reshape(-1)
    if dq.shape != (8,) or not np.all(np.isfinite(dq)):
        raise ValueError(f"dq must be 8 finite numbers [q (w, x, y, z), q' (w, x, y, z)], got {dq.tolist()}")
    if np.linalg.norm(dq[:4]) < 1e-12:
        raise ValueError(f"dq must have a non-zero real part, got {dq.tolist()}")
    return transforms_from_dual_quaternions(dq[None])[0]


def check_unit_dual_quaternions(dq, name: str) -> np.ndarray:
    arr = np.asarray(dq, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 8 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite (n, 8) array of dual quaternions, got shape {arr.shape}")
    norms = np.linalg.norm(arr[:, :4], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-6)
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] must have a unit real part, got norm {norms[bad[0]]:.6g}")
    ortho = np.einsum("ij,ij->i", arr[:, :4], arr[:, 4:])
    scale = 1.0 + np.linalg.norm(arr[:, 4:], axis=1)
    bad = np.flatnonzero(np.abs(ortho) > 1e-6 * scale)
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] is not a unit dual quaternion: q.q' = {ortho[bad[0]]:.3g}, expected 0")
    return arr

