"""Rigid-body geometry: 4x4 transforms ``T_<to>_<from>`` (mm) and rotations in every representation
the study needs (radians; quaternions scalar-first ``[w, x, y, z]``; Euler ``"xyz"`` extrinsic,
``"XYZ"`` intrinsic), on SciPy's :class:`~scipy.spatial.transform.Rotation`, with errors that name
the argument. Conventions: docs/pose-estimation.md, "Frames, rotations and the hand-eye calibration".
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "RIGID_TOLERANCE",
    "as_points",
    "check_rigid",
    "check_rotation",
    "compose",
    "euler_from_matrix",
    "fit_sphere",
    "invert_transform",
    "make_transform",
    "matrix_from_euler",
    "matrix_from_quaternion",
    "matrix_from_rotvec",
    "params_from_transform",
    "quaternion_from_matrix",
    "random_rotation",
    "random_transform",
    "rotation_about_axis",
    "rotation_angle",
    "rotvec_from_matrix",
    "transform_from_params",
    "transform_points",
]

#: Largest deviation from orthonormality (and from the bottom row [0, 0, 0, 1]) accepted as rigid.
RIGID_TOLERANCE = 1e-6


def as_points(points_mm, name: str = "points_mm") -> np.ndarray:
    """Points as a float64 ``(n, 3)`` array.

    Args:
        points_mm: ``(n, 3)`` points, or one point ``(3,)`` (which becomes ``(1, 3)``), in mm.
        name: the argument's name in the error message.

    Returns:
        The points, ``(n, 3)`` float64, in mm.

    Raises:
        ValueError: ``points_mm`` is not ``(n, 3)`` or ``(3,)``.
    """
    arr = np.asarray(points_mm, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == 3:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be an (n, 3) array of points in mm, got shape {arr.shape}")
    return arr


def check_rotation(R, name: str = "R", tol: float = RIGID_TOLERANCE) -> np.ndarray:
    """Validate a 3x3 rotation matrix (finite, orthonormal, det +1).

    Args:
        R: the 3x3 rotation matrix.
        name: the argument's name in the error message.
        tol: largest deviation of ``R @ R.T`` from the identity accepted (:data:`RIGID_TOLERANCE`).

    Returns:
        ``R`` as a float64 ``(3, 3)`` array.

    Raises:
        ValueError: ``R`` is not 3x3, not finite, not orthonormal within ``tol`` or has det < 0.
    """
    arr = np.asarray(R, dtype=np.float64)
    if arr.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 rotation matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    err = np.abs(arr @ arr.T - np.eye(3)).max()
    if err > tol or np.linalg.det(arr) < 0:
        raise ValueError(
            f"{name} must be a proper rotation (R @ R.T == I within {tol:g}, det +1); "
            f"got orthonormality error {err:.3g} and det {np.linalg.det(arr):.6f}"
        )
    return arr


def check_rigid(T, name: str = "T", tol: float = RIGID_TOLERANCE) -> np.ndarray:
    """Validate a 4x4 rigid transform ``T_<to>_<from>`` (rotation, translation in mm).

    Args:
        T: the 4x4 homogeneous transform.
        name: the argument's name in the error message.
        tol: largest deviation from orthonormality, and of the bottom row from ``[0, 0, 0, 1]``.

    Returns:
        ``T`` as a float64 ``(4, 4)`` array.

    Raises:
        ValueError: ``T`` is not 4x4, not finite, its bottom row is not ``[0, 0, 0, 1]`` or its
            rotation block is not a proper rotation (the message names ``name``).
    """
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 rigid transform, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if np.abs(arr[3] - [0.0, 0.0, 0.0, 1.0]).max() > tol:
        raise ValueError(f"{name} must have bottom row [0, 0, 0, 1], got {arr[3].tolist()}")
    check_rotation(arr[:3, :3], name=f"{name}[:3, :3]", tol=tol)
    return arr


def make_transform(R=None, t_mm=None) -> np.ndarray:
    """A 4x4 rigid transform from a rotation and a translation.

    Args:
        R: the 3x3 rotation matrix; None: the identity.
        t_mm: the translation, 3 numbers in mm; None: zero.

    Returns:
        The 4x4 float64 transform ``[[R, t], [0, 1]]``.

    Raises:
        ValueError: ``R`` is not a proper rotation, or ``t_mm`` is not 3 finite numbers.
    """
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = check_rotation(R, "R")
    if t_mm is not None:
        t = np.asarray(t_mm, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t_mm must be 3 finite numbers, got {t_mm!r}")
        T[:3, 3] = t
    return T


def invert_transform(T) -> np.ndarray:
    """The inverse of a rigid transform, exact for rigid input (``R.T``, ``-R.T @ t``).

    Args:
        T: a 4x4 rigid transform ``T_<to>_<from>`` (mm).

    Returns:
        ``T_<from>_<to>``, 4x4 float64.

    Raises:
        ValueError: ``T`` is not rigid (:func:`check_rigid`).
    """
    T = check_rigid(T, "T")
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def compose(*transforms) -> np.ndarray:
    """Matrix product of 4x4 transforms, left to right: ``compose(T_a_b, T_b_c) == T_a_c``."""
    if not transforms:
        raise ValueError("compose needs at least one transform")
    out = np.eye(4)
    for i, T in enumerate(transforms):
        out = out @ check_rigid(T, f"transforms[{i}]")
    return out


def transform_points(T, points_mm) -> np.ndarray:
    """Map points through a transform: ``p' = R p + t``.

    Args:
        T: a 4x4 transform ``T_<to>_<from>`` (mm); its bottom row is not read.
        points_mm: ``(n, 3)`` points, or one ``(3,)``, in mm in the ``<from>`` frame.

    Returns:
        ``(n, 3)`` float64 points in mm in the ``<to>`` frame.

    Raises:
        ValueError: ``T`` is not 4x4, or ``points_mm`` is not ``(n, 3)`` / ``(3,)``.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T must be a 4x4 transform, got shape {T.shape}")
    pts = as_points(points_mm)
    return pts @ T[:3, :3].T + T[:3, 3]


def rotation_about_axis(axis, angle_rad: float) -> np.ndarray:
    """A right-handed rotation by ``angle_rad`` about ``axis``.

    Args:
        axis: the rotation axis, 3 numbers of any length > 0.
        angle_rad: the angle in rad.

    Returns:
        The 3x3 float64 rotation matrix.

    Raises:
        ValueError: ``axis`` is not a non-zero finite 3-vector.
    """
    axis = np.asarray(axis, dtype=np.float64).reshape(-1)
    norm = np.linalg.norm(axis)
    if axis.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"axis must be a non-zero finite 3-vector, got {axis.tolist()}")
    return matrix_from_rotvec(axis / norm * float(angle_rad))


def matrix_from_rotvec(rotvec) -> np.ndarray:
    """The rotation matrix of an axis-angle (rotation) vector.

    Args:
        rotvec: 3 numbers: direction the axis, norm the angle in rad.

    Returns:
        The 3x3 float64 rotation matrix.

    Raises:
        ValueError: ``rotvec`` is not 3 finite numbers.
    """
    rv = np.asarray(rotvec, dtype=np.float64).reshape(-1)
    if rv.shape != (3,) or not np.all(np.isfinite(rv)):
        raise ValueError(f"rotvec must be 3 finite numbers, got {rotvec!r}")
    return Rotation.from_rotvec(rv).as_matrix()


def rotvec_from_matrix(R) -> np.ndarray:
    """The axis-angle vector of a rotation matrix.

    Args:
        R: a 3x3 rotation matrix.

    Returns:
        ``(3,)`` float64: the axis scaled by the angle in rad, in [0, pi].

    Raises:
        ValueError: ``R`` is not a proper rotation (:func:`check_rotation`).
    """
    return Rotation.from_matrix(check_rotation(R)).as_rotvec()


def rotation_angle(R) -> float:
    """The rotation angle of a rotation matrix (e.g. of ``R_est.T @ R_true``, an orientation error).

    Args:
        R: a 3x3 rotation matrix.

    Returns:
        The angle in rad, in [0, pi].

    Raises:
        ValueError: ``R`` is not a proper rotation (:func:`check_rotation`).
    """
    R = check_rotation(R)
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def matrix_from_euler(angles_rad, convention: str = "xyz") -> np.ndarray:
    """The rotation matrix of three Euler angles.

    Args:
        angles_rad: the three angles in rad.
        convention: three axis letters, lower case extrinsic (``"xyz"``: about the fixed x, then y,
            then z; the paper's "Euler angles within [0, 360]"), upper case intrinsic (``"ZYX"``).

    Returns:
        The 3x3 float64 rotation matrix.

    Raises:
        ValueError: ``convention`` is not three axis letters of one case with no axis twice in a row,
            or ``angles_rad`` is not 3 finite numbers.
    """
    _check_euler_convention(convention)
    ang = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
    if ang.shape != (3,) or not np.all(np.isfinite(ang)):
        raise ValueError(f"angles_rad must be 3 finite numbers, got {angles_rad!r}")
    return Rotation.from_euler(convention, ang).as_matrix()


def euler_from_matrix(R, convention: str = "xyz") -> np.ndarray:
    """Three Euler angles in rad for ``convention`` (SciPy's ranges; gimbal lock warns there)."""
    _check_euler_convention(convention)
    return Rotation.from_matrix(check_rotation(R)).as_euler(convention)


def _check_euler_convention(convention: str) -> None:
    ok = (
        isinstance(convention, str)
        and len(convention) == 3
        and (set(convention) <= set("xyz") or set(convention) <= set("XYZ"))
        and convention[0] != convention[1]
        and convention[1] != convention[2]
    )
    if not ok:
        raise ValueError(
            f"convention must be three axis letters, all lower case (extrinsic) or all upper case "
            f"(intrinsic), no axis twice in a row, e.g. 'xyz' or 'ZYX'; got {convention!r}"
        )


def quaternion_from_matrix(R) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` with ``w >= 0`` of a rotation matrix."""
    x, y, z, w = Rotation.from_matrix(check_rotation(R)).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def matrix_from_quaternion(q) -> np.ndarray:
    """Rotation matrix of a quaternion ``[w, x, y, z]`` (normalised here; must be non-zero)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    norm = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"q must be a non-zero finite quaternion [w, x, y, z], got {q.tolist()}")
    w, x, y, z = q / norm
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly from SO(3) (Haar measure) with the given Generator."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return Rotation.random(random_state=rng).as_matrix()


def random_transform(rng: np.random.Generator, translation_range_mm: float = 100.0) -> np.ndarray:
    """Uniform random rotation and a translation uniform in ``[-range, range]`` mm per axis."""
    if not np.isfinite(translation_range_mm) or translation_range_mm < 0:
        raise ValueError(f"translation_range_mm must be finite and >= 0, got {translation_range_mm!r}")
    R = random_rotation(rng)
    t = rng.uniform(-translation_range_mm, translation_range_mm, size=3)
    return make_transform(R, t)


def transform_from_params(params) -> np.ndarray:
    """The 4x4 transform of the 6 pose parameters ``[rx, ry, rz, tx, ty, tz]``.

    The parameterisation of the pose of eq. 3 (§II-B.3): a rotation vector and a translation.

    Args:
        params: 6 numbers: the rotation vector in rad, then the translation in mm.

    Returns:
        The 4x4 float64 rigid transform (e.g. ``T_carm_transducer``).

    Raises:
        ValueError: ``params`` is not 6 finite numbers.
    """
    p = np.asarray(params, dtype=np.float64).reshape(-1)
    if p.shape != (6,) or not np.all(np.isfinite(p)):
        raise ValueError(f"params must be 6 finite numbers [rotvec (rad), t (mm)], got {params!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(p[:3]).as_matrix()
    T[:3, 3] = p[3:]
    return T


def params_from_transform(T) -> np.ndarray:
    """The 6 pose parameters ``[rotvec (rad), t (mm)]`` of a rigid transform."""
    T = check_rigid(T, "T")
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def fit_sphere(points_mm) -> tuple[np.ndarray, float]:
    """The least-squares sphere through points (algebraic fit).

    Solves the linear form ``|p|^2 = 2 c.p + (r^2 - |c|^2)``: exact for points on a sphere, a good
    estimate for noisy ones. Measures the transducer cap (§II-B.1) and the treated zone in the
    post-treatment CBCT (§II-E.3).

    Args:
        points_mm: ``(n, 3)`` points in mm, n >= 4.

    Returns:
        ``(centre_mm, radius_mm)``: the centre ``(3,)`` and the radius, in mm.

    Raises:
        ValueError: ``points_mm`` is not ``(n, 3)``, holds fewer than 4 points, or determines no
            sphere (degenerate, e.g. coplanar).
    """
    pts = as_points(points_mm)
    if len(pts) < 4:
        raise ValueError(f"points_mm must hold at least 4 points to fit a sphere, got {len(pts)}")
    A = np.hstack([2.0 * pts, np.ones((len(pts), 1))])
    b = np.einsum("ij,ij->i", pts, pts)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    centre = sol[:3]
    r2 = sol[3] + centre @ centre
    if not np.isfinite(r2) or r2 <= 0:
        raise ValueError("points_mm do not determine a sphere (degenerate, e.g. coplanar)")
    return centre, float(np.sqrt(r2))
