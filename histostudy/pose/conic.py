"""A circle of known radius from its projected conic (the transducer's 64 mm cutout, §II-B.1): the
ellipse fit to the inner boundary's pixels and the circle's two 3-D poses in closed form (the
two-fold ambiguity of eq. 4). Pixels in the image, mm in the C-arm frame; the derivation is in
docs/pose-estimation.md, "The orientation stage".
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from histostudy.imaging import View

__all__ = ["CirclePose", "EllipseFit", "circle_poses_from_conic", "conic_from_ellipse", "conic_from_points",
           "fit_ellipse_ransac"]


@dataclass(frozen=True)
class EllipseFit:
    """An ellipse in pixel coordinates.

    Attributes:
        centre_px: ``(u, v)`` of the centre.
        semi_axes_px: ``(a, b)`` half-lengths, ``a >= b``.
        angle_rad: angle of the ``a`` axis from the ``u`` (column) axis, in ``(-pi/2, pi/2]``.
        inliers: number of points within the fit's tolerance (for a RANSAC fit), else all.
        n_points: number of points the fit was given.
    """

    centre_px: tuple
    semi_axes_px: tuple
    angle_rad: float
    inliers: int
    n_points: int

    @property
    def conic(self) -> np.ndarray:
        """The 3x3 symmetric conic matrix (:func:`conic_from_ellipse`)."""
        return conic_from_ellipse(self.centre_px, self.semi_axes_px, self.angle_rad)

    @property
    def inlier_fraction(self) -> float:
        return self.inliers / self.n_points if self.n_points else 0.0


@dataclass(frozen=True)
class CirclePose:
    """One of the two 3-D circles a conic allows (:func:`circle_poses_from_conic`).

    Attributes:
        normal: world unit normal of the circle's plane, pointing to the side of the X-ray source
            (``normal . (source - centre) > 0``); the transducer's focal direction is ``+-normal``.
        centre_mm: world position of the circle centre.
    """

    normal: np.ndarray
    centre_mm: np.ndarray


def conic_from_ellipse(centre_px, semi_axes_px, angle_rad) -> np.ndarray:
    """The symmetric 3x3 matrix ``C`` with ``[u, v, 1] C [u, v, 1]^T = 0`` on the ellipse of centre
    ``(u0, v0)``, half-axes ``(a, b)`` and ``a``-axis at ``angle_rad`` from the ``u`` axis;
    normalised to ``C[2, 2] = -1`` after translation, i.e. negative inside the ellipse."""
    u0, v0 = (float(x) for x in centre_px)
    a, b = (float(x) for x in semi_axes_px)
    if not (np.isfinite([u0, v0, a, b, angle_rad]).all() and a > 0 and b > 0):
        raise ValueError(f"ellipse needs a finite centre, semi-axes > 0 and angle; got centre {centre_px!r}, "
                         f"semi_axes {semi_axes_px!r}, angle {angle_rad!r}")
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.array([[c, -s], [s, c]])
    A = R @ np.diag([1.0 / a ** 2, 1.0 / b ** 2]) @ R.T
    centre = np.array([u0, v0])
    C = np.zeros((3, 3))
    C[:2, :2] = A
    C[:2, 2] = C[2, :2] = -A @ centre
    C[2, 2] = centre @ A @ centre - 1.0
    return C


def conic_from_points(points_px) -> np.ndarray:
    """Least-squares conic through ``(n, 2)`` points (n >= 5), Hartley-normalised algebraic fit.

    Exact for points on a conic; the reference the tests compare the ellipse fits with.
    """
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 5 or not np.all(np.isfinite(pts)):
        raise ValueError(f"points_px must hold >= 5 finite (u, v) points, got {len(pts)}")
    mean = pts.mean(axis=0)
    scale = np.sqrt(2.0) / np.mean(np.linalg.norm(pts - mean, axis=1))
    N = np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1.0]])
    x, y = ((pts - mean) * scale).T
    design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    a, b, c, d, e, f = np.linalg.svd(design)[2][-1]
    Cn = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    C = N.T @ Cn @ N
    return C / np.linalg.norm(C)


def _ellipse_from_rotated_rect(rect) -> tuple[np.ndarray, np.ndarray, float]:
    (u0, v0), (w, h), angle_deg = rect
    # OpenCV's RotatedRect: full axis ``w`` along the direction at ``angle_deg`` from the u axis.
    a, b, angle = w / 2.0, h / 2.0, np.deg2rad(angle_deg)
    if b > a:
        a, b, angle = b, a, angle + np.pi / 2
    angle = (angle + np.pi / 2) % np.pi - np.pi / 2
    return np.array([u0, v0]), np.array([a, b]), float(angle)


def _sampson_distance(C: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """First-order geometric distance (px) of points to the conic ``C``."""
    h = np.column_stack([pts, np.ones(len(pts))])
    Ch = h @ C
    algebraic = np.sum(Ch * h, axis=1)
    grad = 2.0 * Ch[:, :2]
    return np.abs(algebraic) / np.maximum(np.linalg.norm(grad, axis=1), 1e-12)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _count_within_px(C: np.ndarray, pts: np.ndarray, tolerance_px: float) -> int:
    """How many of ``pts`` lie within ``tolerance_px`` of the conic ``C`` (Sampson distance, as
    :func:`_sampson_distance`): RANSAC's score of a hypothesis, without numpy's temporaries."""
    count = 0
    for i in range(pts.shape[0]):
        u, v = pts[i, 0], pts[i, 1]
        a0 = u * C[0, 0] + v * C[1, 0] + C[2, 0]
        a1 = u * C[0, 1] + v * C[1, 1] + C[2, 1]
        algebraic = a0 * u + a1 * v + u * C[0, 2] + v * C[1, 2] + C[2, 2]
        gradient = max(np.sqrt(4.0 * a0 * a0 + 4.0 * a1 * a1), 1e-12)
        if abs(algebraic) <= tolerance_px * gradient:
            count += 1
    return count


def fit_ellipse_ransac(points_px, rng: np.random.Generator, *, tolerance_px: float = 3.0, iterations: int = 200,
                       sample_size: int = 6, max_points: int = 4000) -> EllipseFit | None:
    """A robust ellipse through ``(n, 2)`` pixel points: RANSAC over OpenCV's direct least-squares
    fits (``cv2.fitEllipseDirect``, Fitzgibbon's ellipse-specific fit) of small samples, scored by
    the number of points within ``tolerance_px`` (Sampson distance), then refitted on the inliers.

    A segmentation's inner-boundary class is a band several pixels wide with false positives and
    missing stretches: a plain least-squares fit follows the outliers, RANSAC ignores them.
    Returns None when fewer than ``2 * sample_size`` points are given or no sample gives an ellipse.
    ``max_points`` caps the points scored per iteration (a random subset, drawn from ``rng``).
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    for name, value in (("tolerance_px", tolerance_px),):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    for name, value in (("iterations", iterations), ("sample_size", sample_size), ("max_points", max_points)):
        least = 5 if name == "sample_size" else 1
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise ValueError(f"{name} must be an integer >= {5 if name == 'sample_size' else 1}, got {value!r}")
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_px must be finite")
    n_given = len(pts)
    if n_given < 2 * sample_size:
        return None
    if n_given > max_points:
        pts = pts[rng.choice(n_given, size=max_points, replace=False)]
    pts32 = pts.astype(np.float32)
    best_C, best_count = None, -1
    for _ in range(int(iterations)):
        sample = pts32[rng.choice(len(pts32), size=sample_size, replace=False)]
        C = _fit_conic_cv(sample)
        if C is None:
            continue
        count = _count_within_px(C, pts, float(tolerance_px))
        if count > best_count:
            best_C, best_count = C, count
    if best_C is None:
        return None
    # Two refits on the inliers: the second sees the consensus of the first.
    result = None
    for _ in range(2):
        inliers = pts32[_sampson_distance(best_C, pts) <= tolerance_px]
        if len(inliers) < 5:
            break
        rect = cv2.fitEllipseDirect(inliers)
        centre, axes, angle = _ellipse_from_rotated_rect(rect)
        if not (np.all(np.isfinite(axes)) and axes[1] > 0):
            break
        best_C = conic_from_ellipse(centre, axes, angle)
        count = int(np.count_nonzero(_sampson_distance(best_C, pts) <= tolerance_px))
        result = (centre, axes, angle, count)
    if result is None:
        return None
    centre, axes, angle, count = result
    scale = n_given / len(pts)
    return EllipseFit(centre_px=(float(centre[0]), float(centre[1])), semi_axes_px=(float(axes[0]), float(axes[1])),
                      angle_rad=angle, inliers=int(round(count * scale)), n_points=n_given)


def _fit_conic_cv(sample: np.ndarray) -> np.ndarray | None:
    rect = cv2.fitEllipseDirect(sample)
    centre, axes, angle = _ellipse_from_rotated_rect(rect)
    if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(axes)) and axes[1] > 0.5):
        return None
    return conic_from_ellipse(centre, axes, angle)


def _section_circle(Q: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the circle the cone ``r^T Q r = 0`` cuts from the plane ``n . r = 1``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(n, helper)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    p0 = n
    A = np.array([[a @ Q @ a, a @ Q @ b], [b @ Q @ a, b @ Q @ b]])
    g = np.array([a @ Q @ p0, b @ Q @ p0])
    f = p0 @ Q @ p0
    x0 = -np.linalg.solve(A, g)
    k = 0.5 * (A[0, 0] + A[1, 1])
    rho_sq = (g @ np.linalg.solve(A, g) - f) / k
    return p0 + x0[0] * a + x0[1] * b, float(np.sqrt(max(rho_sq, 0.0)))


def circle_poses_from_conic(conic, view: View, radius_mm: float) -> list[CirclePose]:
    """The two world circles of radius ``radius_mm`` that ``view`` images as ``conic`` (3x3, pixels).

    Returns a list of two :class:`CirclePose` (docs/pose-estimation.md for the derivation); raises
    ``ValueError`` when ``conic`` is not an ellipse seen in front of the source (a hyperbola, a
    degenerate conic, or a cone whose eigenvalues do not split two against one).
    """
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.carm.View, got {type(view).__name__}")
    if not (np.isfinite(radius_mm) and radius_mm > 0):
        raise ValueError(f"radius_mm must be finite and > 0, got {radius_mm!r}")
    C = np.asarray(conic, dtype=np.float64)
    if C.shape != (3, 3) or not np.all(np.isfinite(C)):
        raise ValueError(f"conic must be a finite 3x3 matrix, got shape {C.shape}")
    C = 0.5 * (C + C.T)
    if np.linalg.det(C[:2, :2]) <= 0:
        raise ValueError(f"conic is not an ellipse (its quadratic part has determinant "
                         f"{np.linalg.det(C[:2, :2]):.3g} <= 0: a hyperbola, parabola or degenerate conic)")
    M = view.P[:, :3]
    Q = M.T @ C @ M
    Q /= np.linalg.norm(Q)
    lam, vec = np.linalg.eigh(Q)
    if np.count_nonzero(lam > 0) == 1:
        Q, lam, vec = -Q, -lam[::-1], vec[:, ::-1]
    if not (lam[0] < 0 < lam[1] <= lam[2]):
        raise ValueError(f"conic is not an ellipse's cone (eigenvalues of M^T C M: {np.round(lam, 6).tolist()})")
    l3, l2, l1 = lam
    e3, e1 = vec[:, 0], vec[:, 2]
    alpha = np.sqrt((l1 - l2) / (l1 - l3))
    beta = np.sqrt((l2 - l3) / (l1 - l3))
    beam = view.principal_direction
    poses = []
    for sign in (1.0, -1.0):
        n = alpha * e1 + sign * beta * e3
        n /= np.linalg.norm(n)
        c1, rho1 = _section_circle(Q, n)
        if rho1 <= 0:
            raise ValueError("conic's cone has a degenerate circular section")
        c = c1 * (radius_mm / rho1)
        if c @ beam < 0:  # the other nappe of the double cone: behind the source
            c = -c
        normal = n if n @ (-c) > 0 else -n
        poses.append(CirclePose(normal=normal, centre_mm=view.source_mm + c))
    return poses
