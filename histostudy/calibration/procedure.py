"""Hand-eye calibration of the robot to the C-arm (§II-C, eq. 5–8): Daniilidis' dual quaternions.

The chain (frames as in docs/architecture.md, Frames and units; the paper's names in brackets)::

    T_carm_transducer_i  =  T_carm_base  @  T_base_flange_i  @  T_flange_transducer
        [hTc, eq. 5]          [rTc]          [rTe, encoders]     [eTh]

``T_carm_transducer_i`` comes from the 2D/3D pose estimation, ``T_base_flange_i`` from the joint
encoders; ``T_flange_transducer`` (X) and ``T_carm_base`` (Y) are the unknowns, fixed for one
mounting of the transducer and one position of the cart.

Which A and B (derivation; ``tests/test_handeye.py`` proves it on exact data). Write
``F_i = T_base_flange_i``, ``C_i = T_carm_transducer_i``. From the chain, ``Y^-1 C_i = F_i X`` for
every pose, so for two poses i, j::

    (F_j X)^-1 (F_i X) = C_j^-1 C_i   =>   (F_j^-1 F_i) X = X (C_j^-1 C_i)

i.e. ``A X = X B`` with ``A = T_flange_j_flange_i = F_j^-1 F_i`` (the flange motion seen from the
flange) and ``B = T_transducer_j_transducer_i = C_j^-1 C_i`` (the same motion seen from the
transducer), and ``X = T_flange_transducer``. The paper's eq. 6–7 read ``aTb`` as "maps a into b"
(``hTc eTh rTe`` then chains to ``T_carm_base``); in that reading eq. 7 is the same equation
inverted, ``(C_j^-1 C_i) X^-1 = X^-1 (F_j^-1 F_i)``, solved for ``eTh = X^-1``. (The paper says
the dual quaternion q of eq. 8 describes ``rTc``; with eq. 7's A and B it is ``eTh``.) Y then
follows from X pose by pose, ``Y_i = C_i X^-1 F_i^-1``, averaged.

Daniilidis (1999): with the unit dual quaternions ``ǎ = a + ε a'``, ``b̌`` of A and B, and ``q̌`` of
X, ``A X = X B`` is ``ǎ q̌ = q̌ b̌``. When the scalar parts agree (``a0 = b0``, ``a'0 = b'0``: the
screw congruence theorem, true for the *right sign* of ``b̌``), its vector parts are the six linear
equations of eq. 8 per motion::

    [ a - b    [a + b]x    0        0_3x3    ] [q ]
    [ a'- b'   [a'+ b']x   a - b    [a + b]x ] [q'] = 0

Stacked for n motions (6n x 8), the null space is two-dimensional; its basis is the two right
singular vectors of the smallest singular values, and the unit dual quaternion in it is fixed by
``q.q = 1`` and ``q.q' = 0`` (a quadratic in the two coefficients).

Signs: ``q̌`` and ``-q̌`` are one transform, but eq. 8 needs ``ǎ`` and ``b̌`` of each motion to be the
*same-sign* representatives. Making both scalar parts non-negative (OpenCV's fix for issue #24871)
decides that only when the scalar part ``cos(θ/2)`` is clearly non-zero; near θ = 180° it is
noise. Here such motions are signed by agreement with a provisional solution from the decisive
motions (``q b q*`` must point along ``a``), or, when too few motions are decisive, by trying the
sign combinations and keeping the one whose eq. 8 matrix has the best two-dimensional null space;
then everything is solved again. (OpenCV 4.14, scalar rule only, returns X off by tens of degrees
on such data: ``tests/test_handeye.py::test_motions_near_half_turn_keep_consistent_signs``.)

Beyond the paper: :func:`calibration_sensitivity` simulates the calibration error against the
number of poses and the pose-estimation noise.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from histostudy.core import as_generator, atomic_write_json, to_jsonable
from histostudy.geometry import check_rigid, check_rotation, invert_transform, make_transform, matrix_from_rotvec

__all__ = [
    "AXXBSolution",
    "CalibrationError",
    "DegenerateMotionError",
    "HandEyeCalibration",
    "R_BASE_FLANGE_DOWN",
    "calibrate",
    "calibration_sensitivity",
    "daniilidis_matrix",
    "dual_quaternion_from_transform",
    "flange_pose_for_target",
    "motion_pairs",
    "perturb_pose",
    "simulate_poses",
    "solve_axxb",
    "solve_axxb_dual_quaternions",
    "transform_from_dual_quaternion",
]

#: Motions rotating less than this carry no usable axis (default of ``min_rotation_deg``).
MIN_ROTATION_DEG = 1.0
#: Two rotation axes closer than this (or to each other's opposite) count as parallel.
MIN_AXIS_ANGLE_DEG = 2.0
#: ``|cos(θ/2)|`` above which the scalar part decides a motion's dual-quaternion sign
#: (θ < ~168.5°; pose noise moves it by ~½ dθ); below it the sign comes from the solution itself.
SIGN_DECISIVE_SCALAR = 0.1

SCHEMA = "histostudy.handeye/1"


class DegenerateMotionError(ValueError):
    """The motions do not determine X: too little rotation, or all rotation axes parallel."""


class CalibrationError(RuntimeError):
    """A calibration whose residuals exceed the stated bound; targeting must not use it."""


# --------------------------------------------------------------------------- dual quaternions
# Batched helpers: (..., 4) quaternions scalar first, (..., 4, 4) transforms. geometry.py has the
# single-matrix conversions; a calibration with 12 poses has 66 motions, so these run in bulk.


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
            u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
            u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0],
        ],
        axis=-1,
    )


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-first quaternions ``[w, x, y, z]`` (broadcast over leading axes)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    return np.concatenate([pw * qw - np.sum(pv * qv, axis=-1, keepdims=True), pw * qv + qw * pv + _cross(pv, qv)], axis=-1)


def _qconj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _angle(R: np.ndarray):
    """Rotation angle (rad, [0, pi]) of (..., 3, 3) rotations, accurate near 0 too (atan2 of sin
    and cos; ``arccos`` of the trace loses half the digits for small residuals)."""
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    out = np.arctan2(0.5 * np.linalg.norm(v, axis=-1), 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0))
    return float(out) if np.ndim(out) == 0 else out


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` of (..., 3) vectors: ``_skew(v) @ u == np.cross(v, u)``."""
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], axis=-1),
            np.stack([v[..., 2], z, -v[..., 0]], axis=-1),
            np.stack([-v[..., 1], v[..., 0], z], axis=-1),
        ],
        axis=-2,
    )


def _quaternions_from_matrices(R: np.ndarray) -> np.ndarray:
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


def _matrices_from_quaternions(q: np.ndarray) -> np.ndarray:
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


def _dq_from_transforms(T: np.ndarray) -> np.ndarray:
    """(n, 8) unit dual quaternions ``[q, q']`` (``q[0] >= 0``, ``q' = ½ (0, t) q``) of (n, 4, 4)."""
    q = _quaternions_from_matrices(T[:, :3, :3])
    t = np.concatenate([np.zeros((len(T), 1)), T[:, :3, 3]], axis=1)
    return np.concatenate([q, 0.5 * _qmul(t, q)], axis=1)


def _transforms_from_dq(dq: np.ndarray) -> np.ndarray:
    """(n, 4, 4) transforms of (n, 8) dual quaternions (real part normalised; t = 2 q' q*)."""
    norm = np.linalg.norm(dq[:, :4], axis=1, keepdims=True)
    q, qd = dq[:, :4] / norm, dq[:, 4:] / norm
    T = np.zeros((len(dq), 4, 4))
    T[:, :3, :3] = _matrices_from_quaternions(q)
    T[:, :3, 3] = 2.0 * _qmul(qd, _qconj(q))[:, 1:]
    T[:, 3, 3] = 1.0
    return T


def _invert_batch(T: np.ndarray) -> np.ndarray:
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
    return _dq_from_transforms(check_rigid(T, name)[None])[0]


def transform_from_dual_quaternion(dq) -> np.ndarray:
    """4x4 transform of a dual quaternion ``[q, q']`` (``q`` normalised here; t = 2 q' q*)."""
    dq = np.asarray(dq, dtype=np.float64).reshape(-1)
    if dq.shape != (8,) or not np.all(np.isfinite(dq)):
        raise ValueError(f"dq must be 8 finite numbers [q (w, x, y, z), q' (w, x, y, z)], got {dq.tolist()}")
    if np.linalg.norm(dq[:4]) < 1e-12:
        raise ValueError(f"dq must have a non-zero real part, got {dq.tolist()}")
    return _transforms_from_dq(dq[None])[0]


def _as_dq_array(dq, name: str) -> np.ndarray:
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


# --------------------------------------------------------------------------- AX = XB


def daniilidis_matrix(dq_a, dq_b) -> np.ndarray:
    """The 6n x 8 matrix of eq. 8 (Daniilidis 1999, eq. 31) for n motion pairs.

    ``dq_a``, ``dq_b``: ``(n, 8)`` unit dual quaternions of ``A_i`` and ``B_i``, already
    same-signed; the null space holds the dual quaternion of X in ``A_i X = X B_i``. Rows
    ``6i..6i+2``: ``[a - b, [a + b]x, 0, 0]``; rows ``6i+3..6i+5``: ``[a' - b', [a' + b']x, a - b,
    [a + b]x]`` (a, b, a', b' the vector parts of the real and dual quaternions).
    """
    dq_a = np.asarray(dq_a, dtype=np.float64)
    dq_b = np.asarray(dq_b, dtype=np.float64)
    a, ad = dq_a[:, 1:4], dq_a[:, 5:8]
    b, bd = dq_b[:, 1:4], dq_b[:, 5:8]
    S = np.zeros((len(dq_a), 6, 8))
    S[:, :3, 0] = a - b
    S[:, :3, 1:4] = _skew(a + b)
    S[:, 3:, 0] = ad - bd
    S[:, 3:, 1:4] = _skew(ad + bd)
    S[:, 3:, 4] = a - b
    S[:, 3:, 5:8] = _skew(a + b)
    return S.reshape(-1, 8)


@dataclass(frozen=True)
class AXXBSolution:
    """X of ``A_i X = X B_i`` with what the solver saw.

    ``singular_values``: of the eq. 8 matrix, largest first (the last two ~0 for consistent data);
    ``rotation_residuals_deg`` / ``translation_residuals_mm``: per motion, the rotation angle and
    translation norm of ``(A_i X)^-1 (X B_i)``; ``angle_mismatch_deg``: per motion, rotation angle
    of A_i minus that of B_i (zero for consistent data, screw congruence); ``flipped``: motions
    whose ``b̌`` got the sign opposite to the non-negative-scalar rule (decided near 180°).
    """

    X: np.ndarray
    singular_values: np.ndarray
    rotation_residuals_deg: np.ndarray
    translation_residuals_mm: np.ndarray
    angle_mismatch_deg: np.ndarray
    flipped: tuple[int, ...]


def _rotation_of_dq(dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angles (rad, [0, pi]) and unit axes (rows; zero for no rotation) of ``(n, 8)``."""
    v = dq[:, 1:4]
    s = np.linalg.norm(v, axis=1)
    angles = 2.0 * np.arctan2(s, np.abs(dq[:, 0]))
    axes = np.divide(v, s[:, None], out=np.zeros_like(v), where=s[:, None] > 0)
    return angles, axes


def _check_motions(dq_a: np.ndarray, dq_b: np.ndarray, name: str, min_rotation_deg: float, min_axis_angle_deg: float):
    """Raise DegenerateMotionError unless two motions rotate enough about non-parallel axes."""
    ang_a, axes = _rotation_of_dq(dq_a)
    ang_b, _ = _rotation_of_dq(dq_b)
    angle_deg = np.degrees(np.minimum(ang_a, ang_b))
    useful = np.flatnonzero(angle_deg >= min_rotation_deg)
    if useful.size < 2:
        raise DegenerateMotionError(
            f"{name}: hand-eye calibration needs at least two motions rotating by >= {min_rotation_deg:g} deg "
            f"about non-parallel axes; the motion rotation angles are "
            f"{np.round(angle_deg, 4).tolist()} deg ({useful.size} usable). Pure translations do not "
            f"determine the transform: tilt the flange between poses."
        )
    ax = axes[useful]
    cosines = np.clip(np.abs(ax @ ax.T), 0.0, 1.0)
    max_axis_angle = float(np.degrees(np.arccos(cosines.min())))
    if max_axis_angle < min_axis_angle_deg:
        raise DegenerateMotionError(
            f"{name}: all motion rotation axes are parallel (largest angle between two axes "
            f"{max_axis_angle:.4g} deg < min_axis_angle_deg={min_axis_angle_deg:g}); rotations about a "
            f"single axis leave the translation along it undetermined. Rotate about at least two "
            f"different axes."
        )


def _solve_null_space(dq_a: np.ndarray, dq_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit dual quaternion of X from the two-dimensional null space of eq. 8, and the singular values."""
    S = daniilidis_matrix(dq_a, dq_b)
    _, sv, Vt = np.linalg.svd(S, full_matrices=False)
    v1, v2 = Vt[-2], Vt[-1]
    u1, w1, u2, w2 = v1[:4], v1[4:], v2[:4], v2[4:]
    # q = l1 v1 + l2 v2 with q.q' = 0 (homogeneous quadratic form M2) and q.q = 1 (form M1).
    m = 0.5 * (u1 @ w2 + u2 @ w1)
    M2 = np.array([[u1 @ w1, m], [m, u2 @ w2]])
    M1 = np.array([[u1 @ u1, u1 @ u2], [u1 @ u2, u2 @ u2]])
    e, W = np.linalg.eigh(M2)
    if e[0] <= 0.0 <= e[1] and e[1] > e[0]:
        # zero set of the indefinite form: cos(psi) w_0 +- sin(psi) w_1 with e0 cos^2 + e1 sin^2 = 0
        psi = np.arctan2(np.sqrt(-e[0]), np.sqrt(e[1]))
        candidates = [np.cos(psi) * W[:, 0] + s * np.sin(psi) * W[:, 1] for s in (1.0, -1.0)]
    else:
        # Definite form: only for data far from consistent; take the direction nearest q.q' = 0.
        candidates = [W[:, np.argmin(np.abs(e))]]
    # Of the two roots one has a (near-)zero real part (the spurious (0, q) direction of the null
    # space): keep the one with the larger q.q, then scale it to q.q = 1.
    lam = max(candidates, key=lambda c: c @ M1 @ c)
    lam = lam / np.sqrt(lam @ M1 @ lam)
    return lam[0] * v1 + lam[1] * v2, sv


#: Up to this many sign-undecided motions are resolved by trying every sign combination.
MAX_EXHAUSTIVE_SIGNS = 10


def _sign_undecided(dq_a, dq_b, decisive, sign, min_rotation_deg, min_axis_angle_deg):
    """Choose the signs of the ``b̌`` whose scalar part does not decide it (in place in ``dq_b`` and
    ``sign``) and solve. With enough decisive motions, a provisional X from them signs the rest
    (``q b q*`` must point along ``a``). Otherwise every combination is tried and the one whose
    eq. 8 matrix comes closest to a two-dimensional null space (smallest 7th singular value) kept:
    with a wrong sign no X satisfies that motion, so that singular value stays large."""
    undecided = np.flatnonzero(~decisive)
    idx = np.flatnonzero(decisive)
    try:
        _check_motions(dq_a[idx], dq_b[idx], "decisive motions", min_rotation_deg, min_axis_angle_deg)
        dq_x, sv = _solve_null_space(dq_a[idx], dq_b[idx])
    except DegenerateMotionError:
        if undecided.size > MAX_EXHAUSTIVE_SIGNS:
            dq_x, sv = _solve_null_space(dq_a, dq_b)  # best effort, refined by agreement below
        else:
            best = None
            for combo in range(2 ** undecided.size):
                s = np.array([-1.0 if combo >> k & 1 else 1.0 for k in range(undecided.size)])
                trial = dq_b.copy()
                trial[undecided] *= s[:, None]
                sv7 = np.linalg.svd(daniilidis_matrix(dq_a, trial), compute_uv=False)[6]
                if best is None or sv7 < best[0]:
                    best = (sv7, s)
            dq_b[undecided] *= best[1][:, None]
            sign[undecided] *= best[1]
            dq_x, sv = _solve_null_space(dq_a, dq_b)
    # Sign by agreement with the current X, solve with all motions; repeat while signs change.
    for _ in range(3):
        q = dq_x[:4] / np.linalg.norm(dq_x[:4])
        predicted_a = _qmul(_qmul(q, dq_b[undecided, :4]), _qconj(q))
        wrong = undecided[np.einsum("ij,ij->i", predicted_a, dq_a[undecided, :4]) < 0]
        dq_b[wrong] *= -1.0
        sign[wrong] *= -1.0
        dq_x, sv = _solve_null_space(dq_a, dq_b)
        if wrong.size == 0:
            break
    return dq_x, sv


def _solve_dq(dq_a, dq_b, min_rotation_deg, min_axis_angle_deg):
    """Core of the solver on validated (n, 8) arrays: (X, singular values, flipped)."""
    if len(dq_a) < 2:
        raise DegenerateMotionError(f"hand-eye calibration needs at least two motions, got {len(dq_a)}")
    _check_thresholds(min_rotation_deg, min_axis_angle_deg)
    _check_motions(dq_a, dq_b, "motions", min_rotation_deg, min_axis_angle_deg)
    # Scalar parts: take the representatives with non-negative real scalars (OpenCV's fix for
    # #24871); decisive where |cos(θ/2)| is clearly non-zero for both.
    dq_a = dq_a * np.where(dq_a[:, :1] < 0, -1.0, 1.0)
    dq_b = dq_b * np.where(dq_b[:, :1] < 0, -1.0, 1.0)
    decisive = (np.abs(dq_a[:, 0]) > SIGN_DECISIVE_SCALAR) & (np.abs(dq_b[:, 0]) > SIGN_DECISIVE_SCALAR)
    sign = np.ones(len(dq_b))
    if decisive.all():
        dq_x, sv = _solve_null_space(dq_a, dq_b)
    else:
        dq_x, sv = _sign_undecided(dq_a, dq_b, decisive, sign, min_rotation_deg, min_axis_angle_deg)
    # Backstop to the geometric check: rank 6 needed for a two-dimensional null space.
    if sv[5] <= 1e-12 * sv[0]:
        raise DegenerateMotionError(
            f"motions: the eq. 8 matrix has rank < 6 (singular values {np.array2string(sv, precision=3)}); "
            f"the motions do not determine X"
        )
    X = _transforms_from_dq(dq_x[None])[0]
    return X, sv, tuple(int(i) for i in np.flatnonzero(sign < 0))


def _details(A: np.ndarray, B: np.ndarray, X: np.ndarray, sv, flipped) -> AXXBSolution:
    E = _invert_batch(A @ X) @ (X @ B)
    return AXXBSolution(
        X=X,
        singular_values=sv,
        rotation_residuals_deg=np.degrees(_angle(E[:, :3, :3])),
        translation_residuals_mm=np.linalg.norm(E[:, :3, 3], axis=1),
        angle_mismatch_deg=np.degrees(_angle(A[:, :3, :3]) - _angle(B[:, :3, :3])),
        flipped=flipped,
    )


def solve_axxb_dual_quaternions(
    dq_a,
    dq_b,
    *,
    min_rotation_deg: float = MIN_ROTATION_DEG,
    min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
    return_details: bool = False,
):
    """Solve ``A_i X = X B_i`` given the motions as ``(n, 8)`` unit dual quaternions of any signs.

    The sign of each ``b̌_i`` is matched to ``ǎ_i`` by the scalar parts and, where those are not
    decisive (rotations near 180°), by agreement with a provisional solution (module docstring).
    Returns X (4x4) or, with ``return_details``, an :class:`AXXBSolution`.
    """
    dq_a = _as_dq_array(dq_a, "dq_a")
    dq_b = _as_dq_array(dq_b, "dq_b")
    if len(dq_a) != len(dq_b):
        raise ValueError(f"dq_a and dq_b must hold the same number of motions, got {len(dq_a)} and {len(dq_b)}")
    X, sv, flipped = _solve_dq(dq_a, dq_b, min_rotation_deg, min_axis_angle_deg)
    if not return_details:
        return X
    return _details(_transforms_from_dq(dq_a), _transforms_from_dq(dq_b), X, sv, flipped)


def _check_thresholds(min_rotation_deg, min_axis_angle_deg):
    for name, v in (("min_rotation_deg", min_rotation_deg), ("min_axis_angle_deg", min_axis_angle_deg)):
        if not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v) or v < 0 or v >= 180:
            raise ValueError(f"{name} must be a finite angle in [0, 180) deg, got {v!r}")


def _check_transform_list(Ts, name: str, min_len: int) -> np.ndarray:
    """Validate a sequence of 4x4 rigid transforms; returns them stacked (n, 4, 4)."""
    if isinstance(Ts, np.ndarray) and Ts.ndim == 3:
        Ts = list(Ts)
    if not isinstance(Ts, (list, tuple)):
        raise TypeError(f"{name} must be a list of 4x4 rigid transforms, got {type(Ts).__name__}")
    if len(Ts) < min_len:
        raise ValueError(f"{name} must hold at least {min_len} transforms, got {len(Ts)}")
    return np.stack([check_rigid(T, f"{name}[{i}]") for i, T in enumerate(Ts)])


def solve_axxb(
    A_list,
    B_list,
    *,
    min_rotation_deg: float = MIN_ROTATION_DEG,
    min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
    return_details: bool = False,
):
    """X (4x4) with ``A_i @ X == X @ B_i`` for n >= 2 motions, by Daniilidis' dual quaternions (eq. 8).

    ``A_list``, ``B_list``: sequences of 4x4 rigid transforms (mm). For the robot/C-arm chain use
    ``A_i = inv(T_base_flange_j) @ T_base_flange_i`` and ``B_i = inv(T_carm_transducer_j) @
    T_carm_transducer_i``; X is then ``T_flange_transducer`` (module docstring; :func:`calibrate`
    does this). Raises :class:`DegenerateMotionError` when fewer than two motions rotate by at least
    ``min_rotation_deg`` or all their rotation axes lie within ``min_axis_angle_deg`` of each other.
    With ``return_details`` returns an :class:`AXXBSolution` (residuals, singular values).
    """
    A = _check_transform_list(A_list, "A_list", 2)
    B = _check_transform_list(B_list, "B_list", 2)
    if len(A) != len(B):
        raise ValueError(f"A_list and B_list must have the same length, got {len(A)} and {len(B)}")
    X, sv, flipped = _solve_dq(_dq_from_transforms(A), _dq_from_transforms(B), min_rotation_deg, min_axis_angle_deg)
    return _details(A, B, X, sv, flipped) if return_details else X


# --------------------------------------------------------------------------- calibration


def motion_pairs(n_poses: int, pairs: str = "all") -> list[tuple[int, int]]:
    """Pose index pairs (i, j), i < j, that make the motions: ``"all"`` n(n-1)/2 pairs (OpenCV's
    choice), ``"consecutive"`` (i, i+1) — the paper's n-1 motions for n poses."""
    if pairs == "all":
        return [(i, j) for i in range(n_poses) for j in range(i + 1, n_poses)]
    if pairs == "consecutive":
        return [(i, i + 1) for i in range(n_poses - 1)]
    raise ValueError(f"pairs must be 'all' or 'consecutive', got {pairs!r}")


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of (n, 3, 3) rotations: the rotation nearest (Frobenius) to their mean."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


@dataclass
class HandEyeCalibration:
    """Result of :func:`calibrate`: the transducer on the flange and the robot base in the C-arm.

    ``T_flange_transducer`` (paper ``eTh`` as a point map) and ``T_carm_base`` (paper ``rTc``):
    4x4, mm. Per pose i, the chain prediction ``P_i = T_carm_base @ T_base_flange_i @
    T_flange_transducer`` is compared with the pose estimate ``C_i = T_carm_transducer_i``:
    ``rotation_residuals_deg[i]`` = angle of ``R(P_i)^T R(C_i)``; ``translation_residuals_mm[i]`` =
    distance between the transducer origins; ``focal_residuals_mm[i]`` = distance between the focal
    points ``P_i @ f`` and ``C_i @ f`` with ``f = focal_point_transducer_mm`` (the origin by the
    transducer-frame convention of docs/architecture.md, Frames and units, where the two
    residuals coincide). ``motion_*`` are the AX = XB residuals.
    """

    T_flange_transducer: np.ndarray
    T_carm_base: np.ndarray
    rotation_residuals_deg: np.ndarray
    translation_residuals_mm: np.ndarray
    focal_residuals_mm: np.ndarray
    motion_rotation_residuals_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    motion_translation_residuals_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    focal_point_transducer_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    pairs: str = "all"
    method: str = "daniilidis"

    def __post_init__(self):
        self.T_flange_transducer = check_rigid(self.T_flange_transducer, "T_flange_transducer").copy()
        self.T_carm_base = check_rigid(self.T_carm_base, "T_carm_base").copy()
        for name in (
            "rotation_residuals_deg",
            "translation_residuals_mm",
            "focal_residuals_mm",
            "motion_rotation_residuals_deg",
            "motion_translation_residuals_mm",
        ):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1))
        n = len(self.rotation_residuals_deg)
        if len(self.translation_residuals_mm) != n or len(self.focal_residuals_mm) != n:
            raise ValueError(
                f"per-pose residuals must have one value per pose, got lengths {n}, "
                f"{len(self.translation_residuals_mm)}, {len(self.focal_residuals_mm)}"
            )
        f = np.asarray(self.focal_point_transducer_mm, dtype=np.float64).reshape(-1)
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ValueError(f"focal_point_transducer_mm must be 3 finite numbers, got {self.focal_point_transducer_mm!r}")
        self.focal_point_transducer_mm = f

    # ---- summaries
    @property
    def n_poses(self) -> int:
        return len(self.rotation_residuals_deg)

    @property
    def T_base_carm(self) -> np.ndarray:
        return invert_transform(self.T_carm_base)

    @property
    def rms_rotation_residual_deg(self) -> float:
        return float(np.sqrt(np.mean(self.rotation_residuals_deg**2)))

    @property
    def max_rotation_residual_deg(self) -> float:
        return float(np.max(self.rotation_residuals_deg))

    @property
    def rms_translation_residual_mm(self) -> float:
        return float(np.sqrt(np.mean(self.translation_residuals_mm**2)))

    @property
    def max_translation_residual_mm(self) -> float:
        return float(np.max(self.translation_residuals_mm))

    @property
    def rms_focal_residual_mm(self) -> float:
        return float(np.sqrt(np.mean(self.focal_residuals_mm**2)))

    @property
    def max_focal_residual_mm(self) -> float:
        return float(np.max(self.focal_residuals_mm))

    def summary(self) -> dict:
        """The RMS/max residuals and n_poses as a flat dict (for tables)."""
        return {
            "n_poses": self.n_poses,
            "rms_rotation_residual_deg": self.rms_rotation_residual_deg,
            "max_rotation_residual_deg": self.max_rotation_residual_deg,
            "rms_translation_residual_mm": self.rms_translation_residual_mm,
            "max_translation_residual_mm": self.max_translation_residual_mm,
            "rms_focal_residual_mm": self.rms_focal_residual_mm,
            "max_focal_residual_mm": self.max_focal_residual_mm,
        }

    # ---- the gate targeting runs behind
    def check(self, max_focal_residual_mm: float = 2.0, max_rotation_residual_deg: float = 1.0) -> "HandEyeCalibration":
        """Raise :class:`CalibrationError` if any pose's focal-point residual exceeds
        ``max_focal_residual_mm`` or its rotation residual ``max_rotation_residual_deg``; returns
        ``self`` otherwise. The defaults (2 mm, 1°) are the study's bound: about the paper's
        targeting accuracy (1.6 mm mean), far above the residuals of a sound calibration."""
        for name, v in (("max_focal_residual_mm", max_focal_residual_mm), ("max_rotation_residual_deg", max_rotation_residual_deg)):
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        problems = []
        for i, (f, r) in enumerate(zip(self.focal_residuals_mm, self.rotation_residuals_deg)):
            if f > max_focal_residual_mm:
                problems.append(f"pose {i}: focal-point residual {f:.3f} mm > {max_focal_residual_mm:g} mm")
            if r > max_rotation_residual_deg:
                problems.append(f"pose {i}: rotation residual {r:.3f} deg > {max_rotation_residual_deg:g} deg")
        if problems:
            raise CalibrationError(
                "hand-eye calibration residuals exceed the stated bound; targeting refuses to run on it "
                "(re-acquire the poses or check the pose estimates): " + "; ".join(problems)
            )
        return self

    def flange_pose_for_target(self, target_carm_mm, orientation) -> np.ndarray:
        """See :func:`flange_pose_for_target`."""
        return flange_pose_for_target(self, target_carm_mm, orientation)

    def predict_T_carm_transducer(self, T_base_flange) -> np.ndarray:
        """The transducer pose the chain predicts for a flange pose: ``T_carm_base @ F @ X``."""
        F = check_rigid(T_base_flange, "T_base_flange")
        return self.T_carm_base @ F @ self.T_flange_transducer

    # ---- persistence
    def to_dict(self) -> dict:
        """Plain-JSON dict (lists of floats), with a schema tag and the summary for human readers."""
        return to_jsonable(
            {
                "schema": SCHEMA,
                "units": {"length": "mm", "angle": "deg"},
                "method": self.method,
                "pairs": self.pairs,
                "T_flange_transducer": self.T_flange_transducer,
                "T_carm_base": self.T_carm_base,
                "focal_point_transducer_mm": self.focal_point_transducer_mm,
                "rotation_residuals_deg": self.rotation_residuals_deg,
                "translation_residuals_mm": self.translation_residuals_mm,
                "focal_residuals_mm": self.focal_residuals_mm,
                "motion_rotation_residuals_deg": self.motion_rotation_residuals_deg,
                "motion_translation_residuals_mm": self.motion_translation_residuals_mm,
                "summary": self.summary(),
            }
        )

    @classmethod
    def from_dict(cls, d: dict) -> "HandEyeCalibration":
        if not isinstance(d, dict):
            raise TypeError(f"d must be a dict from HandEyeCalibration.to_dict, got {type(d).__name__}")
        if d.get("schema") != SCHEMA:
            raise ValueError(f"d['schema'] must be {SCHEMA!r}, got {d.get('schema')!r}")
        missing = [k for k in ("T_flange_transducer", "T_carm_base", "rotation_residuals_deg",
                               "translation_residuals_mm", "focal_residuals_mm") if k not in d]
        if missing:
            raise ValueError(f"d is missing the keys {missing}")
        return cls(
            T_flange_transducer=np.array(d["T_flange_transducer"], dtype=np.float64),
            T_carm_base=np.array(d["T_carm_base"], dtype=np.float64),
            rotation_residuals_deg=d["rotation_residuals_deg"],
            translation_residuals_mm=d["translation_residuals_mm"],
            focal_residuals_mm=d["focal_residuals_mm"],
            motion_rotation_residuals_deg=d.get("motion_rotation_residuals_deg", []),
            motion_translation_residuals_mm=d.get("motion_translation_residuals_mm", []),
            focal_point_transducer_mm=d.get("focal_point_transducer_mm", [0.0, 0.0, 0.0]),
            pairs=d.get("pairs", "all"),
            method=d.get("method", "daniilidis"),
        )

    def save(self, path) -> Path:
        """Write :meth:`to_dict` as JSON atomically (whole file or none); returns the path."""
        return atomic_write_json(path, self.to_dict())

    @classmethod
    def load(cls, path) -> "HandEyeCalibration":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"path {str(path)!r}: no hand-eye calibration file there")
        return cls.from_dict(json.loads(path.read_text(encoding="utf-8")))


def calibrate(
    T_base_flange_list,
    T_carm_transducer_list,
    *,
    pairs: str = "all",
    focal_point_transducer_mm=(0.0, 0.0, 0.0),
    min_rotation_deg: float = MIN_ROTATION_DEG,
    min_axis_angle_deg: float = MIN_AXIS_ANGLE_DEG,
) -> HandEyeCalibration:
    """Calibrate the robot to the C-arm from n >= 3 poses (§II-C; the paper uses 4).

    ``T_base_flange_list[i]``: flange pose from the encoders (``rTe``); ``T_carm_transducer_list[i]``:
    the pose estimate of the transducer at that flange pose (``hTc``, eq. 5). Solves
    ``(F_j^-1 F_i) X = X (C_j^-1 C_i)`` (eq. 7) over the index ``pairs`` (:func:`motion_pairs`) for
    ``X = T_flange_transducer`` with :func:`solve_axxb`, then ``T_carm_base`` as the chordal mean of
    the rotations of ``C_i X^-1 F_i^-1`` and the translation that fits the focal points
    (``focal_point_transducer_mm``, transducer frame) in least squares given that rotation.
    Raises ``ValueError``/``TypeError`` naming the argument for bad input and
    :class:`DegenerateMotionError` when the poses do not determine the calibration.
    """
    F = _check_transform_list(T_base_flange_list, "T_base_flange_list", 3)
    C = _check_transform_list(T_carm_transducer_list, "T_carm_transducer_list", 3)
    if len(F) != len(C):
        raise ValueError(
            f"T_base_flange_list and T_carm_transducer_list must pair up pose by pose, got {len(F)} and {len(C)} transforms"
        )
    f = np.asarray(focal_point_transducer_mm, dtype=np.float64).reshape(-1)
    if f.shape != (3,) or not np.all(np.isfinite(f)):
        raise ValueError(f"focal_point_transducer_mm must be 3 finite numbers (mm), got {focal_point_transducer_mm!r}")
    i, j = np.array(motion_pairs(len(F), pairs)).T
    A = _invert_batch(F[j]) @ F[i]
    B = _invert_batch(C[j]) @ C[i]
    try:
        X, sv, flipped = _solve_dq(_dq_from_transforms(A), _dq_from_transforms(B), min_rotation_deg, min_axis_angle_deg)
    except DegenerateMotionError as exc:
        raise DegenerateMotionError(
            f"T_base_flange_list / T_carm_transducer_list: the {len(F)} poses do not determine the calibration: {exc}"
        ) from exc
    sol = _details(A, B, X, sv, flipped)
    # Y = C_i X^-1 F_i^-1 for every pose: rotation by the chordal mean, then the translation that
    # fits the focal points best (least squares) given that rotation - the point targeting needs.
    FX = F @ X
    R_Y = _mean_rotation(C[:, :3, :3] @ np.swapaxes(FX[:, :3, :3], 1, 2))
    focal_carm = C[:, :3, :3] @ f + C[:, :3, 3]
    focal_base = FX[:, :3, :3] @ f + FX[:, :3, 3]
    t_Y = np.mean(focal_carm - focal_base @ R_Y.T, axis=0)
    Y = make_transform(R_Y, t_Y)
    P = Y @ FX  # the chain's prediction of every pose estimate
    rot = np.degrees(_angle(np.swapaxes(P[:, :3, :3], 1, 2) @ C[:, :3, :3]))
    trans = np.linalg.norm(P[:, :3, 3] - C[:, :3, 3], axis=1)
    focal = np.linalg.norm((P[:, :3, :3] - C[:, :3, :3]) @ f + P[:, :3, 3] - C[:, :3, 3], axis=1)
    return HandEyeCalibration(
        T_flange_transducer=X,
        T_carm_base=Y,
        rotation_residuals_deg=rot,
        translation_residuals_mm=trans,
        focal_residuals_mm=focal,
        motion_rotation_residuals_deg=sol.rotation_residuals_deg,
        motion_translation_residuals_mm=sol.translation_residuals_mm,
        focal_point_transducer_mm=f,
        pairs=pairs,
    )


def flange_pose_for_target(calibration: HandEyeCalibration, target_carm_mm, orientation) -> np.ndarray:
    """``T_base_flange`` that puts the focal point on ``target_carm_mm`` (C-arm frame, mm).

    ``orientation``: the transducer orientation to keep, a 3x3 ``R_carm_transducer`` or a 4x4
    ``T_carm_transducer`` (e.g. the current pose; only its rotation is used). The desired pose
    ``T_carm_transducer_desired`` has that rotation and places ``focal_point_transducer_mm`` on the
    target; then ``T_base_flange = inv(T_carm_base) @ T_carm_transducer_desired @
    inv(T_flange_transducer)`` (the chain of eq. 6 solved for the flange).
    """
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    target = np.asarray(target_carm_mm, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_carm_mm must be 3 finite numbers (C-arm frame, mm), got {target_carm_mm!r}")
    o = np.asarray(orientation, dtype=np.float64)
    if o.shape == (4, 4):
        R = check_rigid(o, "orientation")[:3, :3]
    elif o.shape == (3, 3):
        R = check_rotation(o, "orientation")
    else:
        raise ValueError(
            f"orientation must be a 3x3 rotation R_carm_transducer or a 4x4 T_carm_transducer, got shape {o.shape}"
        )
    T_des = make_transform(R, target - R @ calibration.focal_point_transducer_mm)
    return invert_transform(calibration.T_carm_base) @ T_des @ invert_transform(calibration.T_flange_transducer)


# --------------------------------------------------------------------------- sensitivity


#: Nominal set-up of the sensitivity study (mm): transducer focal point 250 mm below the flange
#: along the tool axis; flange poses around a point 600 mm out from the base and 550 mm up; the
#: cart placed so that the nominal focal point falls on the isocentre (calibrate where you treat).
NOMINAL_FLANGE_TO_FOCAL_MM = 250.0
NOMINAL_FLANGE_IN_BASE_MM = (600.0, 0.0, 550.0)
#: Nominal downward flange orientation in the base frame (180° about x: tool z points to base -z).
R_BASE_FLANGE_DOWN = np.diag([1.0, -1.0, -1.0])


def simulate_poses(
    n_poses: int,
    T_flange_transducer,
    T_carm_base,
    rng,
    *,
    box_mm: float = 300.0,
    max_tilt_deg: float = 30.0,
    flange_centre_base_mm=NOMINAL_FLANGE_IN_BASE_MM,
):
    """Random reachable-looking flange poses and the transducer poses they give (noise-free).

    Flange origins uniform in a ``box_mm`` cube centred on ``flange_centre_base_mm`` (base frame);
    orientations a rotation vector uniform in the ball of radius ``max_tilt_deg`` about the nominal
    downward orientation (flange z pointing to base -z). Returns ``(T_base_flange list,
    T_carm_transducer list)``.
    """
    rng = as_generator(rng)
    if int(n_poses) != n_poses or n_poses < 1:
        raise ValueError(f"n_poses must be a positive integer, got {n_poses!r}")
    for name, v in (("box_mm", box_mm), ("max_tilt_deg", max_tilt_deg)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    X = check_rigid(T_flange_transducer, "T_flange_transducer")
    Y = check_rigid(T_carm_base, "T_carm_base")
    R_down = R_BASE_FLANGE_DOWN
    centre = np.asarray(flange_centre_base_mm, dtype=np.float64).reshape(3)
    F, C = [], []
    for _ in range(int(n_poses)):
        tilt = _ball(rng, np.radians(max_tilt_deg))
        Fi = make_transform(R_down @ matrix_from_rotvec(tilt), centre + rng.uniform(-box_mm / 2, box_mm / 2, 3))
        F.append(Fi)
        C.append(Y @ Fi @ X)
    return F, C


def perturb_pose(T, translation_sd_mm: float, rotation_sd_deg: float, rng) -> np.ndarray:
    """``T @ dT``: noise in the pose's own frame, about its origin (the focal point for a
    transducer pose): per-axis Gaussian translation (sd in mm) and rotation vector (sd in deg)."""
    rng = as_generator(rng)
    for name, v in (("translation_sd_mm", translation_sd_mm), ("rotation_sd_deg", rotation_sd_deg)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    dT = make_transform(
        matrix_from_rotvec(rng.normal(0.0, np.radians(rotation_sd_deg), 3)), rng.normal(0.0, translation_sd_mm, 3)
    )
    return check_rigid(T, "T") @ dT


def calibration_sensitivity(
    n_poses_list=(4, 8, 12),
    noise_levels=((0.5, 0.2),),
    n_trials: int = 20,
    rng=0,
    *,
    target_carm_mm=(0.0, 0.0, 0.0),
    pairs: str = "all",
    box_mm: float = 300.0,
    max_tilt_deg: float = 30.0,
):
    """Monte-Carlo calibration errors vs number of poses and pose-estimation noise (beyond the paper).

    Per trial: a random true mounting ``T_flange_transducer`` (focal point 250 mm down the tool
    axis ± 20 mm per axis, tilted up to 10°) and cart position ``T_carm_base`` (yaw uniform ±180°,
    tilt up to 2°, placed so that the nominal focal point lies within ±50 mm per axis of the
    isocentre); ``n_poses`` flange poses from :func:`simulate_poses` (box ``box_mm``, tilt
    ``max_tilt_deg``), so the default target, the isocentre, lies inside the calibrated volume; the pose estimates perturbed by :func:`perturb_pose` with
    ``noise_levels`` entries ``(translation sd mm, rotation sd deg)`` per axis; :func:`calibrate`.
    The same poses and truth are reused across noise levels of one trial (paired comparison).

    Returns a DataFrame, one row per (n_poses, noise, trial): ``X_rotation_error_deg``,
    ``X_translation_error_mm`` (of ``T_flange_transducer``), ``Y_rotation_error_deg``,
    ``Y_translation_error_mm`` (of ``T_carm_base``, translation = base origin in the C-arm), and
    ``target_error_mm``: the distance from ``target_carm_mm`` to the true focal point after moving
    the flange to :func:`flange_pose_for_target` of the estimate (orientation: nominal downward),
    plus ``rms_focal_residual_mm`` (what :meth:`HandEyeCalibration.check` sees).
    """
    import pandas as pd

    rng = as_generator(rng)
    n_list = [int(n) for n in n_poses_list]
    if not n_list or min(n_list) < 3:
        raise ValueError(f"n_poses_list must hold pose counts >= 3, got {list(n_poses_list)!r}")
    levels = [tuple(float(x) for x in lv) for lv in noise_levels]
    if not levels or any(len(lv) != 2 or min(lv) < 0 or not np.all(np.isfinite(lv)) for lv in levels):
        raise ValueError(f"noise_levels must be (translation sd mm, rotation sd deg) pairs >= 0, got {noise_levels!r}")
    if int(n_trials) < 1:
        raise ValueError(f"n_trials must be >= 1, got {n_trials!r}")
    target = np.asarray(target_carm_mm, dtype=np.float64).reshape(3)
    rows = []
    for n in n_list:
        for trial in range(int(n_trials)):
            X_true = make_transform(
                matrix_from_rotvec(_ball(rng, np.radians(10.0))),
                [0.0, 0.0, NOMINAL_FLANGE_TO_FOCAL_MM] + rng.uniform(-20.0, 20.0, 3),
            )
            yaw = matrix_from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
            R_Y = matrix_from_rotvec(_ball(rng, np.radians(2.0))) @ yaw
            focal_nominal_base = np.asarray(NOMINAL_FLANGE_IN_BASE_MM) + R_BASE_FLANGE_DOWN @ X_true[:3, 3]
            Y_true = make_transform(R_Y, -R_Y @ focal_nominal_base + rng.uniform(-50.0, 50.0, 3))
            F, C_true = simulate_poses(n, X_true, Y_true, rng, box_mm=box_mm, max_tilt_deg=max_tilt_deg)
            R_nominal = Y_true[:3, :3] @ R_BASE_FLANGE_DOWN @ X_true[:3, :3]
            for t_sd, r_sd in levels:
                C = [perturb_pose(Ci, t_sd, r_sd, rng) for Ci in C_true]
                cal = calibrate(F, C, pairs=pairs)
                F_target = cal.flange_pose_for_target(target, R_nominal)
                focal_true = (Y_true @ F_target @ X_true)[:3, 3]
                E_X = invert_transform(X_true) @ cal.T_flange_transducer
                E_Y = invert_transform(Y_true) @ cal.T_carm_base
                rows.append(
                    {
                        "n_poses": n,
                        "noise_translation_mm": t_sd,
                        "noise_rotation_deg": r_sd,
                        "trial": trial,
                        "X_rotation_error_deg": np.degrees(_angle(E_X[:3, :3])),
                        "X_translation_error_mm": float(np.linalg.norm(cal.T_flange_transducer[:3, 3] - X_true[:3, 3])),
                        "Y_rotation_error_deg": np.degrees(_angle(E_Y[:3, :3])),
                        "Y_translation_error_mm": float(np.linalg.norm(cal.T_carm_base[:3, 3] - Y_true[:3, 3])),
                        "target_error_mm": float(np.linalg.norm(focal_true - target)),
                        "rms_focal_residual_mm": cal.rms_focal_residual_mm,
                    }
                )
    return pd.DataFrame(rows)


def _ball(rng: np.random.Generator, radius: float) -> np.ndarray:
    """A vector uniform in the 3-ball of ``radius``."""
    d = rng.normal(size=3)
    return d / np.linalg.norm(d) * radius * rng.uniform() ** (1 / 3)
