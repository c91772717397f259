"""UR5e kinematics from the nominal Denavit-Hartenberg parameters (§II-C: the base-to-flange transform
``rTe`` of every pose): forward kinematics, and the closed-form inverse (up to eight solutions, unwrapped
within the +-360 deg joint limits). mm and rad."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from histostudy.geometry import check_rigid, invert_transform, matrix_from_rotvec, rotvec_from_matrix

from .base import REACH_MM, UnreachablePoseError

__all__ = [
    "DHSpec",
    "JOINT_LIMIT_RAD",
    "REACH_MM",
    "UR5E",
    "check_joints",
    "forward_kinematics",
    "interpolate_pose",
    "inverse_kinematics",
    "joint_frames",
    "inverse_kinematics_closest",
    "linear_path_joints",
]

#: Every UR5e joint turns +-360 deg.
JOINT_LIMIT_RAD = 2.0 * math.pi
# Below this |sin(theta5)| the wrist is singular (axes 4 and 6 aligned): theta6 is then free.
_WRIST_SINGULAR = 1e-10


@dataclass(frozen=True)
class DHSpec:
    """Standard DH parameters of a 6-axis UR arm: ``d_mm``, ``a_mm`` (mm) and ``alpha_rad`` (rad)."""

    d_mm: tuple[float, ...]
    a_mm: tuple[float, ...]
    alpha_rad: tuple[float, ...]

    def __post_init__(self):
        for name in ("d_mm", "a_mm", "alpha_rad"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (6,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be 6 finite numbers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(v) for v in arr))


#: Nominal UR5e parameters (Universal Robots' published DH table).
UR5E = DHSpec(
    d_mm=(162.5, 0.0, 0.0, 133.3, 99.7, 99.6),
    a_mm=(0.0, -425.0, -392.2, 0.0, 0.0, 0.0),
    alpha_rad=(math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0),
)


def check_joints(q_rad, name: str = "q_rad", limit_rad: float = JOINT_LIMIT_RAD) -> np.ndarray:
    """Validate 6 finite joint angles within +-``limit_rad``; returns float64 (6,)."""
    q = np.asarray(q_rad, dtype=np.float64).reshape(-1)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise ValueError(f"{name} must be 6 finite joint angles in rad, got {q_rad!r}")
    if np.any(np.abs(q) > limit_rad + 1e-12):
        raise ValueError(f"{name} must lie within +-{limit_rad:.6f} rad (+-360 deg), got {q.tolist()}")
    return q


def _link(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _inv(T: np.ndarray) -> np.ndarray:
    # Unchecked rigid inverse for the inner loops (inputs are built here, rigid by construction).
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def forward_kinematics(q_rad, dh: DHSpec = UR5E) -> np.ndarray:
    """The flange pose of joint angles (§II-C): the UR5e's DH chain.

    Args:
        q_rad: 6 joint angles, rad.
        dh: the arm's DH parameters (mm, rad).

    Returns:
        ``T_base_flange``, (4, 4), mm.

    Raises:
        ValueError: ``q_rad`` is not 6 finite numbers.
    """
    q = np.asarray(q_rad, dtype=np.float64).reshape(-1)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise ValueError(f"q_rad must be 6 finite joint angles in rad, got {q_rad!r}")
    T = np.eye(4)
    for i in range(6):
        T = T @ _link(q[i], dh.d_mm[i], dh.a_mm[i], dh.alpha_rad[i])
    return T


def joint_frames(q_rad, dh: DHSpec = UR5E) -> np.ndarray:
    """The arm's link chain: ``(7, 4, 4)`` frames in the base frame (mm) for joint angles ``q_rad``
    (rad, shape (6,)).

    Frame 0 is the base (identity); frame ``i`` (1..6) is the DH frame after joint ``i``, so frame 6
    is ``T_base_flange`` (:func:`forward_kinematics`). The origins ``frames[:, :3, 3]`` are the
    points a stick figure of the arm joins (shoulder, elbow, the three wrists, the flange).
    """
    q = np.asarray(q_rad, dtype=np.float64).reshape(-1)
    if q.shape != (6,) or not np.all(np.isfinite(q)):
        raise ValueError(f"q_rad must be 6 finite joint angles in rad, got {q_rad!r}")
    frames = np.empty((7, 4, 4))
    frames[0] = np.eye(4)
    for i in range(6):
        frames[i + 1] = frames[i] @ _link(q[i], dh.d_mm[i], dh.a_mm[i], dh.alpha_rad[i])
    return frames


def _wrap(angle: float) -> float:
    """Angle wrapped into (-pi, pi]."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


def inverse_kinematics(T_base_flange, dh: DHSpec = UR5E, theta6_free: float = 0.0) -> np.ndarray:
    """All joint solutions reaching ``T_base_flange`` (mm): an ``(n, 6)`` array, n in 0..8, angles in (-pi, pi].

    ``theta6_free`` is used for the last joint where the wrist is singular (sin theta5 = 0), where
    every value of theta6 (with theta4 compensating) reaches the pose. An empty array means the pose
    is out of reach.
    """
    T = check_rigid(T_base_flange, "T_base_flange")
    d1, _, _, d4, d5, d6 = dh.d_mm
    a2, a3 = dh.a_mm[1], dh.a_mm[2]
    if any(abs(v) > 1e-12 for v in (dh.a_mm[0], dh.a_mm[3], dh.a_mm[4], dh.a_mm[5], dh.d_mm[1], dh.d_mm[2])):
        raise ValueError(f"dh must have the UR structure (a1 = a4 = a5 = a6 = d2 = d3 = 0), got {dh!r}")
    p06 = T[:3, 3]
    # Wrist centre of joint 5: back from the flange along its z axis by d6.
    p05 = T @ np.array([0.0, 0.0, -d6, 1.0])
    r05 = math.hypot(p05[0], p05[1])
    solutions: list[list[float]] = []
    if r05 < abs(d4) - 1e-9:
        return np.zeros((0, 6))
    psi = math.atan2(p05[1], p05[0])
    phi = math.acos(min(1.0, abs(d4) / r05)) if r05 > 0 else 0.0
    T60 = _inv(T)
    for s1 in (1.0, -1.0):
        th1 = psi + s1 * phi + math.pi / 2
        c1, sn1 = math.cos(th1), math.sin(th1)
        c5 = (p06[0] * sn1 - p06[1] * c1 - d4) / d6
        if abs(c5) > 1.0 + 1e-9:
            continue
        c5 = min(1.0, max(-1.0, c5))
        for s5 in (1.0, -1.0):
            th5 = s5 * math.acos(c5)
            sin5 = math.sin(th5)
            if abs(sin5) < _WRIST_SINGULAR:
                th6 = theta6_free
            else:
                # x and y axes of the base frame seen from the flange frame.
                X, Y = T60[:3, 0], T60[:3, 1]
                th6 = math.atan2((-X[1] * sn1 + Y[1] * c1) / sin5, (X[0] * sn1 - Y[0] * c1) / sin5)
            T01 = _link(th1, d1, 0.0, dh.alpha_rad[0])
            T45 = _link(th5, d5, 0.0, dh.alpha_rad[4])
            T56 = _link(th6, d6, 0.0, dh.alpha_rad[5])
            T14 = _inv(T01) @ T @ _inv(T45 @ T56)
            px, pz = T14[0, 3], T14[1, 3]
            # Joint 2..4 are parallel: a planar two-link problem in the x/y plane of frame 1.
            r2 = px * px + pz * pz
            c3 = (r2 - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
            if abs(c3) > 1.0 + 1e-9:
                continue
            c3 = min(1.0, max(-1.0, c3))
            for s3 in (1.0, -1.0):
                th3 = s3 * math.acos(c3)
                th2 = math.atan2(pz, px) - math.atan2(a3 * math.sin(th3), a2 + a3 * math.cos(th3))
                T12 = _link(th2, 0.0, a2, dh.alpha_rad[1])
                T23 = _link(th3, 0.0, a3, dh.alpha_rad[2])
                T34 = _inv(T12 @ T23) @ T14
                th4 = math.atan2(T34[1, 0], T34[0, 0])
                solutions.append([_wrap(v) for v in (th1, th2, th3, th4, th5, th6)])
    if not solutions:
        return np.zeros((0, 6))
    sols = np.array(solutions)
    # Guard against numerical drift near the workspace boundary: keep solutions that reproduce T.
    keep = []
    for i, q in enumerate(sols):
        T_check = forward_kinematics(q, dh)
        if np.abs(T_check[:3, 3] - p06).max() < 1e-6 and np.abs(T_check[:3, :3] - T[:3, :3]).max() < 1e-9:
            keep.append(i)
    return sols[keep]


def _unwrap_towards(q: np.ndarray, q_ref: np.ndarray, limit_rad: float) -> np.ndarray | None:
    """Add multiples of 2 pi per joint to get closest to ``q_ref`` within +-limit; None if impossible."""
    out = np.empty(6)
    for j in range(6):
        base = q_ref[j] + _wrap(q[j] - q_ref[j])  # nearest equivalent angle
        candidates = [base + k * 2.0 * math.pi for k in (-1, 0, 1)]
        valid = [c for c in candidates if abs(c) <= limit_rad + 1e-12]
        if not valid:
            return None
        out[j] = min(valid, key=lambda c: abs(c - q_ref[j]))
    return out


def inverse_kinematics_closest(
    T_base_flange, q_near_rad, dh: DHSpec = UR5E, limit_rad: float = JOINT_LIMIT_RAD
) -> np.ndarray:
    """The joint solution reaching a flange pose closest (Euclidean, rad) to given joints (§II-C).

    Each joint is unwrapped by multiples of 2 pi towards ``q_near_rad`` within +-``limit_rad``.

    Args:
        T_base_flange: (4, 4) rigid flange pose in the base frame, mm.
        q_near_rad: 6 joint angles, rad, within +-``limit_rad``.
        dh: the arm's DH parameters (mm, rad), of the UR structure.
        limit_rad: the joint limit, rad (+-360 deg).

    Returns:
        6 joint angles, rad.

    Raises:
        UnreachablePoseError: no solution within the limits.
        ValueError: ``q_near_rad`` invalid, ``T_base_flange`` not rigid, or ``dh`` not of the UR
            structure.
    """
    q_near = check_joints(q_near_rad, "q_near_rad", limit_rad)
    sols = inverse_kinematics(T_base_flange, dh, theta6_free=float(q_near[5]))
    best, best_dist = None, math.inf
    for q in sols:
        qu = _unwrap_towards(q, q_near, limit_rad)
        if qu is None:
            continue
        dist = float(np.linalg.norm(qu - q_near))
        if dist < best_dist:
            best, best_dist = qu, dist
    if best is None:
        p = np.asarray(T_base_flange, dtype=np.float64)[:3, 3]
        raise UnreachablePoseError(
            f"T_base_flange with position {np.round(p, 3).tolist()} mm has no inverse-kinematics solution "
            f"within the joint limits +-{limit_rad:.4f} rad ({len(sols)} solutions before the limits)"
        )
    return best


def interpolate_pose(T_start, T_end, fraction: float) -> np.ndarray:
    """Pose at ``fraction`` in [0, 1] of a straight-line move: linear position, geodesic rotation."""
    T0 = np.asarray(T_start, dtype=np.float64)
    T1 = np.asarray(T_end, dtype=np.float64)
    s = float(fraction)
    T = np.eye(4)
    T[:3, 3] = (1.0 - s) * T0[:3, 3] + s * T1[:3, 3]
    T[:3, :3] = T0[:3, :3] @ matrix_from_rotvec(s * rotvec_from_matrix(T0[:3, :3].T @ T1[:3, :3]))
    return T


def linear_path_joints(
    T_base_tcp_start,
    T_base_tcp_end,
    T_flange_tcp,
    q_start_rad,
    dh: DHSpec = UR5E,
    step_mm: float = 20.0,
    step_rad: float = 0.1,
    max_joint_step_rad: float = 0.5,
    limit_rad: float = JOINT_LIMIT_RAD,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint configurations along a straight TCP path, each solved near the previous one.

    Returns ``(fractions, joints)`` with shapes ``(n,)`` and ``(n, 6)``; the last row reaches
    ``T_base_tcp_end``. Raises :class:`UnreachablePoseError` when a sample has no solution within
    the limits, or when joints jump by more than ``max_joint_step_rad`` between samples (the path
    passes through a singularity, where a real moveL would stop with a protective stop).
    """
    T0 = check_rigid(T_base_tcp_start, "T_base_tcp_start")
    T1 = check_rigid(T_base_tcp_end, "T_base_tcp_end")
    T_tcp_flange = invert_transform(T_flange_tcp)
    dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
    angle = float(np.linalg.norm(rotvec_from_matrix(T0[:3, :3].T @ T1[:3, :3])))
    n = max(1, int(math.ceil(max(dist / step_mm, angle / step_rad))))
    fractions = np.linspace(0.0, 1.0, n + 1)
    q = check_joints(q_start_rad, "q_start_rad", limit_rad)
    rows = [q]
    for s in fractions[1:]:
        T_flange = interpolate_pose(T0, T1, s) @ T_tcp_flange
        try:
            q_next = inverse_kinematics_closest(T_flange, q, dh, limit_rad)
        except UnreachablePoseError as exc:
            raise UnreachablePoseError(
                f"the straight path leaves the reachable set at {100 * s:.0f}% of the move: {exc}"
            ) from None
        jump = float(np.abs(q_next - q).max())
        if jump > max_joint_step_rad:
            raise UnreachablePoseError(
                f"the straight path passes a singularity at {100 * s:.0f}% of the move "
                f"(a joint turns {jump:.3f} rad within one {step_mm:g} mm / {step_rad:g} rad step)"
            )
        rows.append(q_next)
        q = q_next
    return fractions, np.array(rows)

# the 0.1.0 name, deprecated (CHANGELOG.md)
