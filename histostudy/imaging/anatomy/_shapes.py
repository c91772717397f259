"""Analytic convex solids with closed-form X-ray chords (§II-B.2): ellipsoid, oriented box, elliptic
cylinder, and the :class:`Primitive` interface. World frame: CBCT, LPS, mm; a shape's rotation maps its
local axes to the world's; ``mu_per_mm`` in 1/mm, a difference to the surroundings."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from histostudy.geometry import as_points, check_rigid, check_rotation

from ._rays import _chord_from_interval, _Rays, _skew

__all__ = [
    "Box",
    "Ellipsoid",
    "EllipticCylinder",
    "Primitive",
]

_EYE = np.eye(3)


# --------------------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------------------


def _vec3(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be 3 finite numbers in mm, got {value!r}")
    return arr


def _positive3(value, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
        raise ValueError(f"{name} must be 3 finite positive lengths in mm, got {value!r}")
    return arr


def _mu(value) -> float:
    try:
        mu = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"mu_per_mm must be a finite attenuation in 1/mm, got {value!r}") from None
    if not math.isfinite(mu):
        raise ValueError(f"mu_per_mm must be a finite attenuation in 1/mm, got {value!r}")
    return mu


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=np.float64)
    arr.setflags(write=False)
    return arr


# --------------------------------------------------------------------------------------------------
# Primitives
# --------------------------------------------------------------------------------------------------


class Primitive:
    """A solid with a linear attenuation ``mu_per_mm`` [1/mm] (a difference to its surroundings).

    Subclasses provide, for rays from one common origin:

    - ``_interval_fn(origin)``: a function of :class:`_Rays` returning entry and exit distances
      ``(t0, t1)`` in mm along the (unit) rays; a miss is NaN or ``t0 >= t1``. Only convex shapes
      have it (``convex = True``).
    - ``_chord_fn(origin, ahead)``: a function returning the chord length in mm in front of the
      origin. ``ahead=True`` is the caller's promise that the solid lies wholly in front of the
      origin for every ray it passes (true for a C-arm source and a solid in the half-space in
      front of it), which allows a cheaper formula.
    """

    mu_per_mm: float
    name: str
    convex: bool = True

    # --- interface each shape implements --------------------------------------------------------

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World axis-aligned bounding box ``(lo, hi)`` in mm."""
        raise NotImplementedError

    def contains(self, points_mm) -> np.ndarray:
        """Boolean ``(n,)``: which world points (mm) lie inside the solid."""
        raise NotImplementedError

    def transformed(self, T) -> Primitive:
        """The same solid moved by the 4x4 rigid transform ``T`` (world <- world)."""
        raise NotImplementedError

    def _interval_fn(self, origin) -> Callable:
        raise NotImplementedError

    def _chord_fn(self, origin, ahead: bool = False) -> Callable:
        interval = self._interval_fn(origin)

        def chord(rays):
            return _chord_from_interval(*interval(rays))

        return chord

    # --- shared -----------------------------------------------------------------------------

    def chord_lengths(self, origin_mm, directions) -> np.ndarray:
        """Chord length in mm of rays from ``origin_mm`` (3,) along ``directions`` (n, 3).

        Directions are normalised here; only the part of each ray in front of the origin counts.
        """
        origin = _vec3(origin_mm, "origin_mm")
        d = np.asarray(directions, dtype=np.float64)
        if d.ndim == 1 and d.shape[0] == 3:
            d = d[None, :]
        if d.ndim != 2 or d.shape[1] != 3:
            raise ValueError(f"directions must be an (n, 3) array, got shape {d.shape}")
        norm = np.linalg.norm(d, axis=1)
        if not np.all(np.isfinite(norm)) or np.any(norm == 0):
            raise ValueError("directions must be finite and non-zero")
        d = d / norm[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return self._chord_fn(origin)(_Rays(d[:, 0].copy(), d[:, 1].copy(), d[:, 2].copy()))

    def line_integrals_of_rays(self, origin_mm, directions) -> np.ndarray:
        """``mu_per_mm * chord_lengths(...)``: this primitive's share of each ray's line integral."""
        return self.mu_per_mm * self.chord_lengths(origin_mm, directions)

    def _corners(self) -> np.ndarray:
        lo, hi = self.bounds()
        idx = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        return np.where(idx == 0, lo, hi)


class _Oriented(Primitive):
    """Shared parts of shapes given by a centre, a rotation ``R`` (local -> world) and sizes."""

    center_mm: np.ndarray
    R: np.ndarray

    def _init_pose(self):
        object.__setattr__(self, "center_mm", _frozen(_vec3(self.center_mm, "center_mm")))
        object.__setattr__(self, "R", _frozen(check_rotation(self.R, "R")))
        object.__setattr__(self, "mu_per_mm", _mu(self.mu_per_mm))
        object.__setattr__(self, "name", str(self.name))

    def _local(self, points_mm) -> np.ndarray:
        return (as_points(points_mm) - self.center_mm) @ self.R

    def transformed(self, T):
        T = check_rigid(T, "T")
        return dataclasses.replace(self, center_mm=T[:3, :3] @ self.center_mm + T[:3, 3], R=T[:3, :3] @ self.R)


@dataclass(frozen=True, eq=False)
class Ellipsoid(_Oriented):
    """An oriented ellipsoid: ``|diag(1/semi_axes) R^T (x - center)| <= 1``.

    Attributes:
        center_mm: centre in world mm.
        semi_axes_mm: semi-axes (a, b, c) along the local x, y, z axes, mm, all > 0.
        R: 3x3 rotation, local -> world (columns are the local axes in world coordinates).
        mu_per_mm: linear attenuation [1/mm], a difference to the surrounding material.
        name: a label (e.g. "liver").
    """

    center_mm: np.ndarray
    semi_axes_mm: np.ndarray
    R: np.ndarray = field(default_factory=lambda: _EYE.copy())
    mu_per_mm: float = 0.0
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "semi_axes_mm", _frozen(_positive3(self.semi_axes_mm, "semi_axes_mm")))
        self._init_pose()

    def bounds(self):
        half = np.sqrt(((self.R * self.semi_axes_mm) ** 2).sum(axis=1))
        return self.center_mm - half, self.center_mm + half

    def contains(self, points_mm):
        return ((self._local(points_mm) / self.semi_axes_mm) ** 2).sum(axis=1) <= 1.0

    def _setup(self, origin):
        # Scaled local frame, where the ellipsoid is the unit sphere: q = Q d, p = scaled origin.
        Q = self.R.T / self.semi_axes_mm[:, None]
        p = Q @ (origin - self.center_mm)
        G = Q.T @ Q                      # |q|^2 = d^T G d
        C = _skew(p) @ Q                 # p x q = C d
        # Quarter discriminant of |p + t q|^2 = 1: (p.q)^2 - |q|^2 (|p|^2 - 1) = |q|^2 - |p x q|^2.
        # This form has no cancellation between the large terms of (p.q)^2 and |q|^2 |p|^2.
        H = G - C.T @ C
        return p, Q, G, H

    def _interval_fn(self, origin):
        p, Q, G, H = self._setup(origin)
        b = Q.T @ p                      # p.q = b . d

        def interval(rays):
            A = rays.quad(G)
            half = np.sqrt(rays.quad(H)) / A    # NaN (a miss) where the discriminant is negative
            mid = -rays.lin(b) / A
            return mid - half, mid + half

        return interval

    def _chord_fn(self, origin, ahead: bool = False):
        if not ahead:
            return super()._chord_fn(origin)
        _, _, G, H = self._setup(origin)

        def chord(rays):
            # Both intersections lie ahead of the origin: the chord is 2 sqrt(disc) / |q|^2.
            return 2.0 * np.sqrt(np.maximum(rays.quad(H), 0.0)) / rays.quad(G)

        return chord


@dataclass(frozen=True, eq=False)
class Box(_Oriented):
    """An oriented rectangular box: ``|R^T (x - center)| <= half_sizes`` per axis.

    Attributes:
        center_mm: centre in world mm.
        half_sizes_mm: half edge lengths along the local x, y, z axes, mm, all > 0.
        R: 3x3 rotation, local -> world.
        mu_per_mm: linear attenuation [1/mm], a difference to the surrounding material.
        name: a label.
    """

    center_mm: np.ndarray
    half_sizes_mm: np.ndarray
    R: np.ndarray = field(default_factory=lambda: _EYE.copy())
    mu_per_mm: float = 0.0
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "half_sizes_mm", _frozen(_positive3(self.half_sizes_mm, "half_sizes_mm")))
        self._init_pose()

    def bounds(self):
        half = np.abs(self.R) @ self.half_sizes_mm
        return self.center_mm - half, self.center_mm + half

    def contains(self, points_mm):
        return np.all(np.abs(self._local(points_mm)) <= self.half_sizes_mm, axis=1)

    def _interval_fn(self, origin):
        o = self.R.T @ (origin - self.center_mm)
        axes = [(self.R[:, k], -self.half_sizes_mm[k] - o[k], self.half_sizes_mm[k] - o[k]) for k in range(3)]

        def interval(rays):
            t0 = t1 = None
            for axis, lo, hi in axes:
                inv = 1.0 / rays.lin(axis)        # +-inf for a ray parallel to the slab
                ta, tb = lo * inv, hi * inv
                # fmin/fmax ignore the NaN of 0 * inf (ray in a face plane): a grazing ray, chord 0.
                near, far = np.fmin(ta, tb), np.fmax(ta, tb)
                t0 = near if t0 is None else np.maximum(t0, near)
                t1 = far if t1 is None else np.minimum(t1, far)
            return t0, t1

        return interval


@dataclass(frozen=True, eq=False)
class EllipticCylinder(_Oriented):
    """An oriented elliptic cylinder of finite length, its axis along the local z axis.

    Attributes:
        center_mm: centre (middle of the axis) in world mm.
        semi_axes_mm: semi-axes (a, b) of the cross-section along local x and y, mm, > 0.
        half_length_mm: half the length along the local z axis, mm, > 0.
        R: 3x3 rotation, local -> world (``R[:, 2]`` is the axis direction).
        mu_per_mm: linear attenuation [1/mm], a difference to the surrounding material.
        name: a label (e.g. "body").
    """

    center_mm: np.ndarray
    semi_axes_mm: np.ndarray
    half_length_mm: float
    R: np.ndarray = field(default_factory=lambda: _EYE.copy())
    mu_per_mm: float = 0.0
    name: str = ""

    def __post_init__(self):
        ab = np.asarray(self.semi_axes_mm, dtype=np.float64).reshape(-1)
        if ab.shape != (2,) or not np.all(np.isfinite(ab)) or not np.all(ab > 0):
            raise ValueError(f"semi_axes_mm must be 2 finite positive lengths (a, b) in mm, got {self.semi_axes_mm!r}")
        object.__setattr__(self, "semi_axes_mm", _frozen(ab))
        h = float(self.half_length_mm)
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"half_length_mm must be a finite positive length in mm, got {self.half_length_mm!r}")
        object.__setattr__(self, "half_length_mm", h)
        self._init_pose()

    def bounds(self):
        a, b = self.semi_axes_mm
        half = np.sqrt((self.R[:, 0] * a) ** 2 + (self.R[:, 1] * b) ** 2) + np.abs(self.R[:, 2]) * self.half_length_mm
        return self.center_mm - half, self.center_mm + half

    def contains(self, points_mm):
        loc = self._local(points_mm)
        return (((loc[:, :2] / self.semi_axes_mm) ** 2).sum(axis=1) <= 1.0) & (np.abs(loc[:, 2]) <= self.half_length_mm)

    def _interval_fn(self, origin):
        a, b = self.semi_axes_mm
        q0, q1 = self.R[:, 0] / a, self.R[:, 1] / b     # scaled cross-section coordinates q = (q0.d, q1.d)
        o = self.R.T @ (origin - self.center_mm)
        p0, p1 = o[0] / a, o[1] / b
        axis, oz, h = self.R[:, 2], o[2], self.half_length_mm
        origin_in_section = p0 * p0 + p1 * p1 < 1.0

        def interval(rays):
            # Linear forms (not a quadratic form as for the ellipsoid) keep the discriminant's sign
            # right for rays nearly along the axis, where |q| is tiny.
            x, y = rays.lin(q0), rays.lin(q1)
            A = x * x + y * y
            cross = p0 * y - p1 * x
            half = np.sqrt(A - cross * cross) / A
            mid = -(p0 * x + p1 * y) / A
            t0, t1 = mid - half, mid + half
            parallel = A == 0.0
            if parallel.any():
                # A ray exactly along the axis never crosses the mantle: inside the section it is
                # bounded by the end caps only, outside it misses.
                inf = np.inf if origin_in_section else np.nan
                t0, t1 = np.where(parallel, -inf, t0), np.where(parallel, inf, t1)
            inv = 1.0 / rays.lin(axis)
            ta, tb = (-h - oz) * inv, (h - oz) * inv
            t0 = np.maximum(t0, np.fmin(ta, tb))
            t1 = np.minimum(t1, np.fmax(ta, tb))
            return t0, t1

        return interval
