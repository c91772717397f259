"""The AX = XB solver of §II-C (eq. 8): Daniilidis' dual quaternions (Daniilidis 1999), with the
signs of motions near a half turn decided by agreement rather than by their scalar parts. A, B
and X are 4x4 rigid transforms in mm; the derivation and the sign rule are in
docs/pose-estimation.md, "The chain and AX = XB".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from histostudy.geometry import check_rigid

from .dual_quaternion import (
    check_unit_dual_quaternions,
    dual_quaternions_from_transforms,
    invert_transforms,
    quaternion_conjugate,
    quaternion_product,
    rotation_angles_rad,
    skew_matrices,
    transforms_from_dual_quaternions,
)

__all__ = ["AXXBSolution", "DegenerateMotionError", "daniilidis_matrix", "solve_axxb", "solve_axxb_dual_quaternions"]

#: Motions rotating less than this carry no usable axis (default of ``min_rotation_deg``).
MIN_ROTATION_DEG = 1.0
#: Two rotation axes closer than this (or to each other's opposite) count as parallel.
MIN_AXIS_ANGLE_DEG = 2.0
#: ``|cos(θ/2)|`` above which the scalar part decides a motion's dual-quaternion sign
#: (θ < ~168.5°; pose noise moves it by ~½ dθ); below it the sign comes from the solution itself.
SIGN_DECISIVE_SCALAR = 0.1


class DegenerateMotionError(ValueError):
    """The motions do not determine X: too little rotation, or all rotation axes parallel."""


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
    S[:, :3, 1:4] = skew_matrices(a + b)
    S[:, 3:, 0] = ad - bd
    S[:, 3:, 1:4] = skew_matrices(ad + bd)
    S[:, 3:, 4] = a - b
    S[:, 3:, 5:8] = skew_matrices(a + b)
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
        predicted_a = quaternion_product(quaternion_product(q, dq_b[undecided, :4]), quaternion_conjugate(q))
        wrong = undecided[np.einsum("ij,ij->i", predicted_a, dq_a[undecided, :4]) < 0]
        dq_b[wrong] *= -1.0
        sign[wrong] *= -1.0
        dq_x, sv = _solve_null_space(dq_a, dq_b)
        if wrong.size == 0:
            break
    return dq_x, sv


def solve_motion_dual_quaternions(dq_a, dq_b, min_rotation_deg, min_axis_angle_deg):
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
    X = transforms_from_dual_quaternions(dq_x[None])[0]
    return X, sv, tuple(int(i) for i in np.flatnonzero(sign < 0))


def solution_details(A: np.ndarray, B: np.ndarray, X: np.ndarray, sv, flipped) -> AXXBSolution:
    """The :class:`AXXBSolution` of X for the motions ``A``, ``B`` ((n, 4, 4), mm): residuals per motion."""
    E = invert_transforms(A @ X) @ (X @ B)
    return AXXBSolution(
        X=X,
        singular_values=sv,
        rotation_residuals_deg=np.degrees(rotation_angles_rad(E[:, :3, :3])),
        translation_residuals_mm=np.linalg.norm(E[:, :3, 3], axis=1),
        angle_mismatch_deg=np.degrees(rotation_angles_rad(A[:, :3, :3]) - rotation_angles_rad(B[:, :3, :3])),
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
    decisive (rotations near 180°), by agreement with a provisional solution (docs/pose-estimation.md).
    Returns X (4x4) or, with ``return_details``, an :class:`AXXBSolution`.
    """
    dq_a = check_unit_dual_quaternions(dq_a, "dq_a")
    dq_b = check_unit_dual_quaternions(dq_b, "dq_b")
    if len(dq_a) != len(dq_b):
        raise ValueError(f"dq_a and dq_b must hold the same number of motions, got {len(dq_a)} and {len(dq_b)}")
    X, sv, flipped = solve_motion_dual_quaternions(dq_a, dq_b, min_rotation_deg, min_axis_angle_deg)
    if not return_details:
        return X
    A, B = transforms_from_dual_quaternions(dq_a), transforms_from_dual_quaternions(dq_b)
    return solution_details(A, B, X, sv, flipped)


def _check_thresholds(min_rotation_deg, min_axis_angle_deg):
    for name, v in (("min_rotation_deg", min_rotation_deg), ("min_axis_angle_deg", min_axis_angle_deg)):
        if not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v) or v < 0 or v >= 180:
            raise ValueError(f"{name} must be a finite angle in [0, 180) deg, got {v!r}")


def check_transform_list(Ts, name: str, min_len: int) -> np.ndarray:
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
    T_carm_transducer_i``; X is then ``T_flange_transducer`` (docs/pose-estimation.md; :func:`calibrate`
    does this). Raises :class:`DegenerateMotionError` when fewer than two motions rotate by at least
    ``min_rotation_deg`` or all their rotation axes lie within ``min_axis_angle_deg`` of each other.
    With ``return_details`` returns an :class:`AXXBSolution` (residuals, singular values).
    """
    A = check_transform_list(A_list, "A_list", 2)
    B = check_transform_list(B_list, "B_list", 2)
    if len(A) != len(B):
        raise ValueError(f"A_list and B_list must have the same length, got {len(A)} and {len(B)}")
    X, sv, flipped = solve_motion_dual_quaternions(
        dual_quaternions_from_transforms(A), dual_quaternions_from_transforms(B), min_rotation_deg, min_axis_angle_deg
    )
    return solution_details(A, B, X, sv, flipped) if return_details else X
