"""Synthetic patient and phantom backgrounds: exact X-ray line integrals of analytic 3-D scenes.

Stands in for the real projections the paper superimposed the transducer on (§II-B.2: "hybrid
images ... real x-ray projections from 12 porcine studies", converted to line integrals of the
linear attenuation coefficient) and for the phantom set-up of §II-D (Fig. 4A: an agarose
phantom in a degassed water bath on the patient table). Instead of recorded projections we
project a random analytic 3-D scene exactly, so that both biplane views see one consistent body.

World frame: the CBCT frame, millimetres, origin at the isocentre, DICOM LPS axes (+x patient
left, +y posterior, +z head). The patient lies supine, the table under the back (+y side); the
transducer's water bath sits on the anterior surface (-y side), its focal point near the
isocentre.

A scene is a list of primitives, each a solid with a linear attenuation ``mu_per_mm`` [1/mm].
Primitives add: ``mu`` is the *difference* to whatever else is there (bowel gas inside soft
tissue is about -0.02 /mm, bone inside soft tissue about +0.02..0.03 /mm). A line integral is the
dimensionless ``sum(mu * chord length in mm)`` over primitives, the quantity the C-arm's
preprocessing delivers (``-log(I / I0)``).

Every chord is computed in closed form (a quadratic for ellipsoids and elliptic cylinders, the
slab method for boxes); the composites :class:`Intersection` and :class:`Difference` combine the
entry/exit distances of convex shapes, e.g. a body flattened against the table, or a water bath
whose water fills the space around the body's curved surface.
"""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from histostudy.geometry import as_points, check_rigid, check_rotation, rotation_about_axis
from .carm import View

__all__ = [
    "AbdomenParams",
    "Anatomy",
    "Background",
    "Box",
    "Difference",
    "Ellipsoid",
    "EllipticCylinder",
    "Intersection",
    "MIXED_ABDOMEN_PROBABILITY",
    "PhantomParams",
    "Primitive",
    "StaticBackground",
    "random_abdomen",
    "random_background",
    "random_phantom_setup",
]

#: Probability of an animal (abdomen) background in ``kind="mixed"``: the paper's segmentation
#: evaluation had 156 animal and 56 phantom images (§III-A).
MIXED_ABDOMEN_PROBABILITY = 156.0 / (156.0 + 56.0)

# Rows per work unit of the renderer: ~40k rays per band keeps the temporaries of one primitive in
# the CPU cache, and bands are what the worker threads share out. Fixed (not tied to the number of
# workers) so the image is bit-identical for any ``workers``.
_BAND_ROWS = 32

_EYE = np.eye(3)


# --------------------------------------------------------------------------------------------------
# Rays
# --------------------------------------------------------------------------------------------------


class _Rays:
    """Unit ray directions (three same-shaped arrays) from one common origin.

    The pairwise products of the direction components are computed once per band and shared by
    every primitive: with a common origin an ellipsoid's discriminant is a quadratic form in the
    direction, ``d^T H d``, so each primitive costs a handful of multiply-adds per ray.
    """

    __slots__ = ("d", "_prod", "_parent", "_index")

    def __init__(self, dx, dy, dz, parent=None, index=None):
        self.d = (dx, dy, dz)
        self._prod = None
        self._parent = parent
        self._index = index

    @property
    def shape(self):
        return self.d[0].shape

    def products(self):
        """``(xx, yy, zz, xy, xz, yz)``, computed lazily and shared with sub-views."""
        if self._prod is None:
            if self._parent is not None:
                self._prod = tuple(p[self._index] for p in self._parent.products())
            else:
                x, y, z = self.d
                self._prod = (x * x, y * y, z * z, x * y, x * z, y * z)
        return self._prod

    def sub(self, index) -> "_Rays":
        """The rays at ``index`` (a tuple of slices) of these, sharing the products."""
        return _Rays(*(c[index] for c in self.d), parent=self, index=index)

    def lin(self, v) -> np.ndarray:
        """``v . d`` for a 3-vector ``v`` (zero coefficients skipped: axis-aligned shapes)."""
        out = None
        for coef, comp in zip(v, self.d):
            if coef != 0.0:
                term = coef * comp
                out = term if out is None else out + term
        return np.zeros(self.shape) if out is None else out

    def quad(self, H) -> np.ndarray:
        """``d^T H d`` for a symmetric 3x3 ``H``."""
        xx, yy, zz, xy, xz, yz = self.products()
        out = None
        for coef, comp in ((H[0, 0], xx), (H[1, 1], yy), (H[2, 2], zz),
                           (2.0 * H[0, 1], xy), (2.0 * H[0, 2], xz), (2.0 * H[1, 2], yz)):
            if coef != 0.0:
                term = coef * comp
                out = term if out is None else out + term
        return np.zeros(self.shape) if out is None else out


def _chord_from_interval(t0, t1):
    """Length of ``[max(t0, 0), t1]`` (only the part in front of the origin), 0 for a miss (NaN)."""
    c = t1 - np.maximum(t0, 0.0)
    return np.where(c > 0.0, c, 0.0)


def _skew(p) -> np.ndarray:
    """Cross-product matrix: ``_skew(p) @ q == np.cross(p, q)``."""
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


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

    def transformed(self, T) -> "Primitive":
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


@dataclass(frozen=True, eq=False)
class Intersection(Primitive):
    """The intersection of convex shapes (itself convex), with its own ``mu_per_mm``.

    The operands only give the shape; their ``mu_per_mm`` is ignored. Example: a body elliptic
    cylinder intersected with a box whose face is flattened against the table.
    """

    parts: tuple
    mu_per_mm: float = 0.0
    name: str = ""

    def __post_init__(self):
        parts = tuple(self.parts)
        if len(parts) < 1:
            raise ValueError("parts must hold at least one convex shape, got none")
        for i, part in enumerate(parts):
            if not isinstance(part, Primitive) or not part.convex:
                raise ValueError(f"parts[{i}] must be a convex Primitive (Ellipsoid, Box, EllipticCylinder, "
                                 f"Intersection), got {type(part).__name__}")
        object.__setattr__(self, "parts", parts)
        object.__setattr__(self, "mu_per_mm", _mu(self.mu_per_mm))
        object.__setattr__(self, "name", str(self.name))

    def bounds(self):
        los, his = zip(*(p.bounds() for p in self.parts))
        return np.max(los, axis=0), np.min(his, axis=0)

    def contains(self, points_mm):
        return np.logical_and.reduce([p.contains(points_mm) for p in self.parts])

    def transformed(self, T):
        return dataclasses.replace(self, parts=tuple(p.transformed(T) for p in self.parts))

    def _interval_fn(self, origin):
        fns = [p._interval_fn(origin) for p in self.parts]

        def interval(rays):
            t0, t1 = fns[0](rays)
            for fn in fns[1:]:
                s0, s1 = fn(rays)
                # np.maximum/minimum propagate NaN, so a miss of any operand is a miss.
                t0, t1 = np.maximum(t0, s0), np.minimum(t1, s1)
            return t0, t1

        return interval


@dataclass(frozen=True, eq=False)
class Difference(Primitive):
    """``keep`` minus ``remove`` (both convex), with its own ``mu_per_mm``; not itself convex.

    The chord is ``chord(keep) - chord(keep and remove)``, exact for convex operands. Examples:
    the water of a bath pressed onto the curved abdomen (bath box minus body), a tank's walls
    (outer box minus an inner box open at the top).
    """

    keep: Primitive
    remove: Primitive
    mu_per_mm: float = 0.0
    name: str = ""
    convex = False

    def __post_init__(self):
        for arg in ("keep", "remove"):
            part = getattr(self, arg)
            if not isinstance(part, Primitive) or not part.convex:
                raise ValueError(f"{arg} must be a convex Primitive (Ellipsoid, Box, EllipticCylinder, "
                                 f"Intersection), got {type(part).__name__}")
        object.__setattr__(self, "mu_per_mm", _mu(self.mu_per_mm))
        object.__setattr__(self, "name", str(self.name))

    def bounds(self):
        return self.keep.bounds()

    def contains(self, points_mm):
        return self.keep.contains(points_mm) & ~self.remove.contains(points_mm)

    def transformed(self, T):
        return dataclasses.replace(self, keep=self.keep.transformed(T), remove=self.remove.transformed(T))

    def _interval_fn(self, origin):
        raise TypeError("a Difference is not convex and has no single entry/exit interval")

    def _chord_fn(self, origin, ahead: bool = False):
        keep, remove = self.keep._interval_fn(origin), self.remove._interval_fn(origin)

        def chord(rays):
            a0, a1 = keep(rays)
            b0, b1 = remove(rays)
            return _chord_from_interval(a0, a1) - _chord_from_interval(np.maximum(a0, b0), np.minimum(a1, b1))

        return chord


# --------------------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------------------


@runtime_checkable
class Background(Protocol):
    """Anything that gives a float32 ``(rows, cols)`` line-integral image for a view."""

    def line_integrals(self, view: View) -> np.ndarray: ...


def _pixel_rect(prim: Primitive, view: View):
    """``(rect, ahead)``: the pixels whose ray may hit ``prim`` and whether it is wholly in front.

    ``rect = (r0, r1, c0, c1)`` (ends exclusive). The image of a box in front of the source is the
    convex hull of its projected corners, so the rectangle around those corners (plus one pixel
    for sub-pixel ray offsets) holds every pixel centre whose ray can meet the primitive; ``rect``
    is None when that is off the detector, and the whole detector when part of the box is behind
    the source. ``ahead``: every corner has ``w > 0``, so every hit along a pixel ray is at t > 0
    (along such a ray ``w`` grows in proportion to t).
    """
    rows, cols = view.shape
    uvw = view.project_homogeneous(prim._corners())
    if not np.all(uvw[:, 2] > 1e-6):
        return (0, rows, 0, cols), False
    uv = uvw[:, :2] / uvw[:, 2:3]
    (umin, vmin), (umax, vmax) = uv.min(axis=0), uv.max(axis=0)
    c0, c1 = max(0, int(math.floor(umin)) - 1), min(cols, int(math.floor(umax)) + 2)
    r0, r1 = max(0, int(math.floor(vmin)) - 1), min(rows, int(math.floor(vmax)) + 2)
    if c0 >= c1 or r0 >= r1:
        return None, True
    return (r0, r1, c0, c1), True


@dataclass(frozen=True, eq=False)
class Anatomy:
    """An analytic 3-D scene (a patient or a phantom set-up) as a list of primitives.

    Attributes:
        primitives: the :class:`Primitive` solids; their attenuations add.
        name: a label.
        kind: ``"abdomen"``, ``"phantom"`` or ``"custom"``.
        meta: the drawn parameters and landmarks (e.g. ``anterior_skin_y_mm``, ``bath_top_y_mm``)
            in world mm, for placing the transducer and for provenance.
    """

    primitives: tuple
    name: str = ""
    kind: str = "custom"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        prims = tuple(self.primitives)
        for i, p in enumerate(prims):
            if not isinstance(p, Primitive):
                raise ValueError(f"primitives[{i}] must be a Primitive, got {type(p).__name__}")
        object.__setattr__(self, "primitives", prims)

    def __len__(self) -> int:
        return len(self.primitives)

    def attenuation(self, points_mm) -> np.ndarray:
        """Linear attenuation [1/mm] at world points ``(n, 3)`` mm: the sum over primitives."""
        pts = as_points(points_mm)
        mu = np.zeros(len(pts))
        for p in self.primitives:
            mu += np.where(p.contains(pts), p.mu_per_mm, 0.0)
        return mu

    def transformed(self, T) -> "Anatomy":
        """The whole scene moved by the rigid 4x4 transform ``T`` (world <- world)."""
        T = check_rigid(T, "T")
        return dataclasses.replace(self, primitives=tuple(p.transformed(T) for p in self.primitives))

    def line_integrals(self, view: View, *, oversample: int = 1, cull: bool = True,
                       workers: int | None = 1) -> np.ndarray:
        """Float32 ``(rows, cols)`` line integrals (dimensionless) of the scene seen by ``view``.

        Each pixel's ray runs from ``view.source_mm`` through the pixel centre (integer pixel
        coordinates, u = column, v = row); ``oversample=n`` averages n x n rays per pixel
        (a box-filtered detector pixel). ``cull`` evaluates each primitive only inside the
        rectangle its projected bounding box covers (the image is identical either way).
        ``workers`` threads share the rows; the result does not depend on it. The default is 1:
        on 2 cores threads only paid off for scenes of a few large primitives (per-call overhead
        of the many small ones holds the GIL).
        """
        if not isinstance(view, View):
            raise TypeError(f"view must be a histostudy.imaging.carm.View, got {type(view).__name__}")
        if isinstance(oversample, bool) or not isinstance(oversample, (int, np.integer)) or oversample < 1:
            raise ValueError(f"oversample must be a positive integer (rays per pixel side), got {oversample!r}")
        if workers is None:
            workers = 1
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
        rows, cols = view.shape
        source = view.source_mm
        full = (0, rows, 0, cols)
        jobs = []
        with np.errstate(divide="ignore", invalid="ignore"):
            for prim in self.primitives:
                if prim.mu_per_mm == 0.0:
                    continue
                rect, ahead = _pixel_rect(prim, view)
                if not cull:
                    rect = full
                if rect is not None:
                    jobs.append((prim.mu_per_mm, prim._chord_fn(source, ahead), rect))
        n = int(oversample)
        offsets = [((i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5) for j in range(n) for i in range(n)]
        out = np.zeros((rows, cols), dtype=np.float32)
        col_px = np.arange(cols, dtype=np.float64)

        def render_band(r0: int) -> None:
            r1 = min(rows, r0 + _BAND_ROWS)
            acc = np.zeros((r1 - r0, cols))
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                for du, dv in offsets:
                    uu, vv = np.meshgrid(col_px + du, np.arange(r0, r1, dtype=np.float64) + dv)
                    d = view.ray_directions(np.stack([uu.ravel(), vv.ravel()], axis=1))
                    d = d.T.reshape(3, r1 - r0, cols)
                    rays = _Rays(d[0], d[1], d[2])
                    for mu, fn, (pr0, pr1, pc0, pc1) in jobs:
                        a, b = max(r0, pr0), min(r1, pr1)
                        if a >= b:
                            continue
                        index = (slice(a - r0, b - r0), slice(pc0, pc1))
                        acc[index] += mu * fn(rays.sub(index))
            out[r0:r1] = acc / len(offsets)

        starts = range(0, rows, _BAND_ROWS)
        if workers == 1:
            for r0 in starts:
                render_band(r0)
        else:
            with ThreadPoolExecutor(max_workers=int(workers)) as pool:
                list(pool.map(render_band, starts))
        return out


@dataclass(frozen=True, eq=False)
class StaticBackground:
    """A user's own line-integral projection for one view (e.g. a real porcine frame).

    Attributes:
        image: ``(rows, cols)`` line integrals (dimensionless, ``-log(I / I0)``), stored as float32.
        view: optionally the view the image belongs to; then ``line_integrals`` refuses any other.
        name: a label (e.g. the source file).
    """

    image: np.ndarray
    view: View | None = None
    name: str = ""
    kind: str = "static"

    def __post_init__(self):
        img = np.array(self.image, dtype=np.float32)
        if img.ndim != 2 or img.size == 0:
            raise ValueError(f"image must be a non-empty 2-D (rows, cols) array, got shape {img.shape}")
        if not np.all(np.isfinite(img)):
            raise ValueError("image must hold finite line integrals, found NaN or inf")
        if self.view is not None:
            if not isinstance(self.view, View):
                raise TypeError(f"view must be a View or None, got {type(self.view).__name__}")
            if self.view.shape != img.shape:
                raise ValueError(f"image shape {img.shape} does not match view {self.view.name!r} "
                                 f"shape {self.view.shape}")
        img.setflags(write=False)
        object.__setattr__(self, "image", img)

    def line_integrals(self, view: View, **_ignored) -> np.ndarray:
        """A float32 copy of the image; ``view`` must have the image's shape (and be ``self.view``'s geometry)."""
        if not isinstance(view, View):
            raise TypeError(f"view must be a histostudy.imaging.carm.View, got {type(view).__name__}")
        if tuple(view.shape) != self.image.shape:
            raise ValueError(f"view {view.name!r} has shape {view.shape}, but the static background "
                             f"{self.name!r} is {self.image.shape}")
        if self.view is not None and not np.allclose(view.P, self.view.P, rtol=1e-9, atol=1e-9):
            raise ValueError(f"the static background {self.name!r} belongs to view {self.view.name!r}, "
                             f"not to view {view.name!r} (projection matrices differ)")
        return self.image.copy()


# --------------------------------------------------------------------------------------------------
# Random scenes: parameters
# --------------------------------------------------------------------------------------------------


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _range(name: str, value, integer: bool = False) -> tuple:
    """``value`` as a ``(low, high)`` range of finite floats; a bare number ``v`` is ``(v, v)``."""
    if _is_number(value):
        value = (value, value)
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (low, high) range or a number, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"{name} must be a finite range with low <= high, got {value!r}")
    if integer and (lo != int(lo) or hi != int(hi) or lo < 0):
        raise ValueError(f"{name} must be a range of non-negative integers, got {value!r}")
    return (lo, hi)


def _normalise_params(params) -> None:
    """Validate a params dataclass in place: every field a range, a tuple of ranges (one per
    component, as in its default) or, for ``*_probability`` fields, a probability."""
    int_fields = getattr(params, "_INT_FIELDS", frozenset())
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        if f.name.endswith("_probability"):
            if not (_is_number(value) and 0.0 <= float(value) <= 1.0):
                raise ValueError(f"{f.name} must be a probability in [0, 1], got {value!r}")
            norm = float(value)
        elif isinstance(f.default, tuple) and f.default and isinstance(f.default[0], tuple):
            # One range per component, e.g. three semi-axes; a flat sequence fixes each component.
            k = len(f.default)
            if not isinstance(value, (tuple, list)) or len(value) != k:
                raise ValueError(f"{f.name} must be {k} ranges (low, high), one per component, got {value!r}")
            norm = tuple(_range(f"{f.name}[{i}]", v) for i, v in enumerate(value))
        else:
            norm = _range(f.name, value, integer=f.name in int_fields)
        object.__setattr__(params, f.name, norm)


def _with_overrides(cls, params, overrides: dict):
    if params is None:
        params = cls()
    elif not isinstance(params, cls):
        raise TypeError(f"params must be a {cls.__name__} or None, got {type(params).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} field(s) {unknown}; expected some of {sorted(names)}")
    return dataclasses.replace(params, **overrides)


class _Draw:
    """Uniform draws from the named ranges of a params dataclass, recording what was drawn."""

    def __init__(self, rng: np.random.Generator, params):
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.rng, self.params, self.drawn = rng, params, {}

    def __call__(self, name: str):
        """A float from a range field, an array (one value per component) from a tuple of ranges."""
        value = getattr(self.params, name)
        if isinstance(value[0], tuple):
            out = np.array([self.rng.uniform(lo, hi) for lo, hi in value])
            self.drawn[name] = out.tolist()
            return out
        out = float(self.rng.uniform(*value))
        self.drawn[name] = out
        return out

    def integer(self, name: str) -> int:
        lo, hi = getattr(self.params, name)
        value = int(self.rng.integers(int(lo), int(hi) + 1))
        self.drawn[name] = value
        return value

    def uniform(self, lo, hi, size=None):
        return self.rng.uniform(lo, hi, size=size)


@dataclass(frozen=True)
class AbdomenParams:
    """Ranges ``(low, high)`` the random abdomen draws from (uniform); lengths mm, mu in 1/mm.

    Effective attenuation at ~70 keV: water/soft tissue 0.019-0.021 /mm, fat ~0.017, cortical
    bone ~0.045-0.05, air ~0. Organ, bone and gas values are *differences* to soft tissue. The
    body outline is porcine/human-abdomen sized; positions of organs are fractions of the
    body's inner (sub-fat) semi-axes so they scale with the body.
    """

    # body outline and placement
    body_width_mm: tuple = (300.0, 380.0)          # left-right
    body_depth_mm: tuple = (200.0, 260.0)          # anterior-posterior
    body_length_mm: tuple = (700.0, 900.0)         # along z
    back_flattening_mm: tuple = (5.0, 25.0)        # flat contact face on the table
    body_shift_x_mm: tuple = (-30.0, 30.0)         # body axis left-right of the isocentre
    body_shift_z_mm: tuple = (-60.0, 60.0)         # body centre head-feet of the isocentre
    body_yaw_deg: tuple = (-4.0, 4.0)              # body axis not quite parallel to the table axis
    target_depth_mm: tuple = (50.0, 110.0)         # isocentre (focal point) below the anterior skin
    fat_mm: tuple = (8.0, 30.0)                    # subcutaneous fat layer
    mu_fat_per_mm: tuple = (0.0165, 0.0175)
    mu_soft_tissue_per_mm: tuple = (0.0195, 0.0210)
    # organs: ellipsoids in the body frame. *_center_frac: centre (x, y) as fractions of the inner
    # semi-axes (+x left, +y posterior); *_z_offset_mm: centre z above the isocentre. Organs
    # reaching into the fat are shrunk to fit. mu: differences to soft tissue.
    organ_tilt_deg: tuple = (-20.0, 20.0)          # each organ's rotation about z (and y)
    liver_center_frac: tuple = ((-0.42, -0.30), (-0.15, 0.0))
    liver_z_offset_mm: tuple = (-20.0, 100.0)
    liver_semi_axes_mm: tuple = ((55.0, 75.0), (50.0, 65.0), (80.0, 105.0))
    liver_delta_mu: tuple = (0.0005, 0.0015)
    kidney_lateral_frac: tuple = (0.30, 0.40)      # |x| from the spine, fraction of the inner half width
    kidney_anterior_mm: tuple = (0.0, 15.0)        # centre anterior of the vertebral bodies
    kidney_z_offset_mm: tuple = (-30.0, 60.0)
    kidney_semi_axes_mm: tuple = ((25.0, 32.0), (20.0, 27.0), (45.0, 60.0))
    kidney_delta_mu: tuple = (0.0005, 0.0012)
    spleen_center_frac: tuple = ((0.40, 0.55), (0.05, 0.30))
    spleen_z_offset_mm: tuple = (30.0, 110.0)
    spleen_semi_axes_mm: tuple = ((20.0, 30.0), (40.0, 55.0), (50.0, 70.0))
    spleen_delta_mu: tuple = (0.0005, 0.0012)
    stomach_center_frac: tuple = ((0.15, 0.35), (-0.35, -0.15))
    stomach_z_offset_mm: tuple = (40.0, 120.0)
    stomach_semi_axes_mm: tuple = ((50.0, 70.0), (35.0, 50.0), (45.0, 65.0))
    stomach_delta_mu: tuple = (-0.0008, 0.0)       # mostly fluid content
    stomach_gas_probability: float = 0.7
    stomach_gas_radius_frac: tuple = (0.25, 0.5)   # of the stomach's smallest semi-axis
    # spine (vertebral bodies + posterior elements)
    spine_depth_mm: tuple = (60.0, 85.0)           # back skin to vertebral body centre
    spine_shift_x_mm: tuple = (-8.0, 8.0)
    spine_half_extent_mm: tuple = (250.0, 250.0)   # spine modelled within this z of the isocentre
    vertebral_body_width_mm: tuple = (40.0, 52.0)
    vertebral_body_depth_frac: tuple = (0.34, 0.40)  # AP semi-axis per width (a kidney-shaped oval)
    vertebral_body_height_mm: tuple = (22.0, 30.0)
    disc_mm: tuple = (5.0, 9.0)
    vertebra_delta_mu: tuple = (0.010, 0.016)      # trabecular body with its thin cortex
    posterior_elements_delta_mu: tuple = (0.016, 0.024)
    # ribs (pairs counted from the lowest one up)
    rib_pairs: tuple = (5, 8)
    rib_lowest_z_mm: tuple = (-20.0, 90.0)         # posterior end of the lowest rib, world z
    rib_spacing_mm: tuple = (26.0, 36.0)
    rib_thickness_mm: tuple = (6.0, 9.0)
    rib_height_mm: tuple = (10.0, 14.0)
    rib_drop_mm: tuple = (25.0, 55.0)              # how far a rib descends from back to front
    rib_delta_mu: tuple = (0.012, 0.020)
    rib_inset_mm: tuple = (4.0, 12.0)              # ribs this far inside the fat
    rib_span_lowest_deg: tuple = (85.0, 105.0)     # arc of the lowest (floating) rib; +28 deg per rib up
    rib_span_max_deg: tuple = (190.0, 210.0)       # ...up to this (ribs reaching round to the front)
    rib_start_x_mm: tuple = (40.0, 55.0)           # |x| of a rib's posterior angle
    # bowel gas (mu = -soft tissue: air replaces tissue)
    gas_pockets: tuple = (3, 9)
    gas_semi_axis_mm: tuple = (6.0, 25.0)
    gas_region_frac: tuple = ((-0.7, 0.7), (-0.8, 0.2))   # centres (x, y), fractions of inner semi-axes
    gas_z_extent_mm: tuple = (150.0, 150.0)        # pockets within this z of the isocentre
    # carbon-fibre table under the back
    table_width_mm: tuple = (450.0, 520.0)
    table_thickness_mm: tuple = (35.0, 55.0)
    table_shift_x_mm: tuple = (-20.0, 20.0)
    table_mu_per_mm: tuple = (0.0025, 0.0040)      # sandwich of carbon skins and foam, averaged
    # water bath on the anterior surface
    bath_probability: float = 1.0                  # 0: no bath (a bare animal projection)
    bath_width_mm: tuple = (220.0, 300.0)
    bath_length_mm: tuple = (200.0, 300.0)
    bath_height_mm: tuple = (100.0, 160.0)         # water column above the skin apex
    bath_sink_mm: tuple = (15.0, 40.0)             # membrane pressed into the soft abdomen
    bath_shift_mm: tuple = (-30.0, 30.0)           # bath centre off the isocentre in x and z
    bath_wall_mm: tuple = (3.0, 6.0)
    mu_water_per_mm: tuple = (0.0192, 0.0198)
    mu_plastic_per_mm: tuple = (0.021, 0.024)      # PMMA/polycarbonate tank walls

    _INT_FIELDS = frozenset({"rib_pairs", "gas_pockets"})

    def __post_init__(self):
        _normalise_params(self)


@dataclass(frozen=True)
class PhantomParams:
    """Ranges for the phantom studies' scene (§II-D, Fig. 4): a 5x5x5 cm agarose phantom on a
    plastic stand in a degassed water tank on the table. Lengths mm, mu in 1/mm."""

    phantom_edge_mm: tuple = (50.0, 50.0)
    phantom_offset_mm: tuple = ((-10.0, 10.0),) * 3   # phantom centre off the isocentre (x, y, z)
    phantom_yaw_deg: tuple = (-30.0, 30.0)         # rotation about the vertical axis
    agarose_delta_mu: tuple = (0.0002, 0.0010)     # agarose gel + red cells vs. water
    layered_probability: float = 1.0               # the layered barium phantom of §II-D.1
    layer_mm: tuple = (3.5, 4.5)
    barium_delta_mu: tuple = (0.004, 0.008)        # ~2.5 % w/v BaSO4
    stand_height_mm: tuple = (20.0, 60.0)
    stand_half_width_mm: tuple = (20.0, 30.0)
    tank_inner_width_mm: tuple = (280.0, 380.0)    # x
    tank_inner_length_mm: tuple = (220.0, 320.0)   # z
    tank_inner_height_mm: tuple = (220.0, 300.0)   # y
    tank_wall_mm: tuple = (4.0, 8.0)
    tank_shift_mm: tuple = (-40.0, 40.0)           # tank centre off the phantom, in x and z
    water_fill: tuple = (0.75, 0.92)               # water level as a fraction of the tank height
    mu_water_per_mm: tuple = (0.0192, 0.0198)
    mu_plastic_per_mm: tuple = (0.021, 0.024)
    table_width_mm: tuple = (450.0, 520.0)
    table_thickness_mm: tuple = (35.0, 55.0)
    table_mu_per_mm: tuple = (0.0025, 0.0040)

    def __post_init__(self):
        _normalise_params(self)


# --------------------------------------------------------------------------------------------------
# Random scenes: builders
# --------------------------------------------------------------------------------------------------


def _rot_x_rad(rad: float) -> np.ndarray:
    return rotation_about_axis([1.0, 0.0, 0.0], rad)


def _rot_y_deg(deg: float) -> np.ndarray:
    return rotation_about_axis([0.0, 1.0, 0.0], np.deg2rad(deg))


def _rot_z_deg(deg: float) -> np.ndarray:
    return rotation_about_axis([0.0, 0.0, 1.0], np.deg2rad(deg))


def _rot_z_rad(rad: float) -> np.ndarray:
    return rotation_about_axis([0.0, 0.0, 1.0], rad)


def _frame_from_axis(axis, up_hint) -> np.ndarray:
    """Rotation whose local z is ``axis`` and local y is as close to ``up_hint`` as possible."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    y = np.asarray(up_hint, float) - z * (z @ up_hint)
    if np.linalg.norm(y) < 1e-9:
        y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def _table(draw: _Draw, table_top_y: float, center_x: float) -> Box:
    thick = draw("table_thickness_mm")
    return Box([center_x, table_top_y + thick / 2.0, 0.0], [draw("table_width_mm") / 2.0, thick / 2.0, 1000.0],
               mu_per_mm=draw("table_mu_per_mm"), name="table")


def random_abdomen(rng: np.random.Generator, params: AbdomenParams | None = None, **overrides) -> Anatomy:
    """A random porcine/human-like abdomen on the table with a water bath on its anterior side.

    Stands in for the 12 porcine studies whose projections the paper's hybrid training images
    were built on (§II-B.2) and for the animal images of the evaluation (§III). The scene: an
    elliptic body (flattened on the table) of fat around soft tissue, liver, kidneys, spleen,
    stomach (with a gas cap when drawn), a vertebral column (bodies, pedicles, lamina, spinous
    and transverse processes) along z, rib pairs as arcs around the body wall, bowel-gas pockets,
    a carbon-fibre table slab and a plastic water bath (water filling down to the skin). The
    isocentre lies ``target_depth_mm`` below the anterior skin. World frame: CBCT, mm, LPS.

    Args:
        rng: the Generator every random draw comes from (same seed -> identical scene).
        params: the ranges to draw from; default :class:`AbdomenParams`.
        **overrides: fields of :class:`AbdomenParams` to replace, a range ``(lo, hi)`` or a number.
    """
    p = _with_overrides(AbdomenParams, params, overrides)
    draw = _Draw(rng, p)
    prims: list[Primitive] = []

    # --- body frame: origin at the body centre, axis along z; world = R_body @ x + t_body -------
    A, B = draw("body_width_mm") / 2.0, draw("body_depth_mm") / 2.0
    half_len = draw("body_length_mm") / 2.0
    flat = draw("back_flattening_mm")
    sx, sz = draw("body_shift_x_mm"), draw("body_shift_z_mm")
    R_body = _rot_y_deg(draw("body_yaw_deg"))
    depth = draw("target_depth_mm")
    # The vertical line through the isocentre stays vertical in the body frame (yaw is about y);
    # place the body so that the skin on that line is `depth` anterior of the isocentre.
    xb = (R_body.T @ np.array([-sx, 0.0, -sz]))[0]
    if abs(xb) >= 0.8 * A:
        raise ValueError(f"body_shift_x_mm {sx:.1f} puts the isocentre outside the body (half width {A:.1f} mm)")
    cy = -depth + B * math.sqrt(1.0 - (xb / A) ** 2)
    t_body = np.array([sx, cy, sz])
    T_body = np.eye(4)
    T_body[:3, :3], T_body[:3, 3] = R_body, t_body
    target_b = R_body.T @ (-t_body)             # the isocentre in body coordinates
    back_y = B - flat                           # flat back face, body frame

    def body_shape(inset: float) -> Intersection:
        cyl = EllipticCylinder([0, 0, 0], [A - inset, B - inset], half_len - inset)
        cut = Box([0.0, (back_y - inset - B - 10.0) / 2.0, 0.0],
                  [A + 10.0, (back_y - inset + B + 10.0) / 2.0, half_len + 10.0])
        return Intersection((cyl, cut))

    mu_fat, mu_soft = draw("mu_fat_per_mm"), draw("mu_soft_tissue_per_mm")
    fat = draw("fat_mm")
    Ai, Bi = A - fat, B - fat                  # inner (sub-fat) semi-axes
    local: list[Primitive] = [
        dataclasses.replace(body_shape(0.0), mu_per_mm=mu_fat, name="body (fat)"),
        dataclasses.replace(body_shape(fat), mu_per_mm=mu_soft - mu_fat, name="body (soft tissue)"),
    ]
    tz = target_b[2]

    # --- organs --------------------------------------------------------------------------------
    u = draw.uniform
    theta = np.linspace(0.0, 2.0 * np.pi, 721)
    ring = np.stack([Ai * np.cos(theta), Bi * np.sin(theta)], axis=1)   # inner outline, body frame

    def clearance(c) -> float:
        """Radius of the largest ball around ``c`` inside the soft tissue (2 mm margin)."""
        radial = float(np.min(np.hypot(ring[:, 0] - c[0], ring[:, 1] - c[1])))
        inside = (c[0] / Ai) ** 2 + (c[1] / Bi) ** 2 < 1.0
        r = min(radial, back_y - fat - c[1], half_len - fat - abs(c[2])) if inside else 0.0
        return r - 2.0

    def organ(center, axes, R, mu, name) -> Ellipsoid:
        # Shrink an organ that would reach into the fat, so organs stay inside the soft tissue.
        axes = np.asarray(axes, float)
        axes = axes * min(1.0, max(0.3, clearance(center) / axes.max()))
        return Ellipsoid(center, axes, R, mu, name)

    def tilt():
        return _rot_z_deg(draw("organ_tilt_deg")) @ _rot_y_deg(draw("organ_tilt_deg"))

    def at(frac_name: str, z_name: str) -> np.ndarray:
        fx, fy = draw(frac_name)
        return np.array([fx * Ai, fy * Bi, tz + draw(z_name)])

    local.append(organ(at("liver_center_frac", "liver_z_offset_mm"), draw("liver_semi_axes_mm"), tilt(),
                       draw("liver_delta_mu"), "liver"))
    spine_y = back_y - draw("spine_depth_mm")
    spine_x = draw("spine_shift_x_mm")
    kd = draw("kidney_delta_mu")
    for side in (-1.0, 1.0):
        c = np.array([spine_x + side * draw("kidney_lateral_frac") * Ai, spine_y - draw("kidney_anterior_mm"),
                      tz + draw("kidney_z_offset_mm")])
        local.append(organ(c, draw("kidney_semi_axes_mm"), tilt(), kd, "kidney"))
    local.append(organ(at("spleen_center_frac", "spleen_z_offset_mm"), draw("spleen_semi_axes_mm"), tilt(),
                       draw("spleen_delta_mu"), "spleen"))
    stomach = organ(at("stomach_center_frac", "stomach_z_offset_mm"), draw("stomach_semi_axes_mm"), tilt(),
                    draw("stomach_delta_mu"), "stomach")
    local.append(stomach)
    # Bounding balls of the negative primitives and of what they must not overlap: gas may only
    # replace tissue that is there, so that no line integral (or attenuation) becomes negative.
    gas_balls: list[tuple[np.ndarray, float]] = []
    avoid: list[tuple[np.ndarray, float]] = [(stomach.center_mm, float(stomach.semi_axes_mm.max()))]
    if rng.random() < p.stomach_gas_probability:
        s_min = float(stomach.semi_axes_mm.min())
        r_gas = draw("stomach_gas_radius_frac") * s_min
        # Supine: gas rises to the anterior (-y) side. A ball with |c' - c| + r <= the smallest
        # semi-axis lies inside the stomach.
        c_gas = stomach.center_mm + np.array([0.0, -(s_min - r_gas) * u(0.5, 0.95), 0.0])
        local.append(Ellipsoid(c_gas, [r_gas, r_gas * u(0.5, 0.9), r_gas],
                               mu_per_mm=-(mu_soft + stomach.mu_per_mm), name="stomach gas"))
        gas_balls.append((c_gas, r_gas))

    # --- vertebral column --------------------------------------------------------------------
    vb_w = draw("vertebral_body_width_mm")
    vb_h = draw("vertebral_body_height_mm")
    disc = draw("disc_mm")
    mu_vb, mu_post = draw("vertebra_delta_mu"), draw("posterior_elements_delta_mu")
    extent = draw("spine_half_extent_mm")
    pitch = vb_h + disc
    z_lo, z_hi = max(tz - extent, -half_len + 20), min(tz + extent, half_len - 20)
    phase = u(0.0, pitch)
    a_vb, b_vb = vb_w / 2.0, vb_w * draw("vertebral_body_depth_frac")
    for zc in np.arange(z_lo + phase, z_hi, pitch):
        y_canal = spine_y + b_vb + 9.0            # centre of the spinal canal
        local += [
            EllipticCylinder([spine_x, spine_y, zc], [a_vb, b_vb], vb_h / 2.0, mu_per_mm=mu_vb, name="vertebral body"),
            Box([spine_x, y_canal + 12.0, zc], [12.0, 3.5, vb_h * 0.38], mu_per_mm=mu_post, name="lamina"),
            Box([spine_x, y_canal + 28.0, zc - 4.0], [3.0, 14.0, vb_h * 0.25], _rot_x_rad(-0.35),
                mu_per_mm=mu_post, name="spinous process"),
        ]
        for side in (-1.0, 1.0):
            local += [
                Ellipsoid([spine_x + side * 11.0, y_canal, zc], [4.0, 8.5, 6.5], mu_per_mm=mu_post, name="pedicle"),
                Ellipsoid([spine_x + side * 30.0, y_canal + 4.0, zc], [14.0, 4.0, 5.0], _rot_z_rad(side * 0.25),
                          mu_per_mm=mu_post, name="transverse process"),
            ]

    # --- ribs: arcs of short elliptic cylinders just inside the fat -------------------------------
    n_ribs = draw.integer("rib_pairs")
    z_rib = draw("rib_lowest_z_mm") - t_body[2]      # body frame (yaw ignored: a few degrees)
    spacing = draw("rib_spacing_mm")
    rib_t, rib_h = draw("rib_thickness_mm"), draw("rib_height_mm")
    drop, mu_rib = draw("rib_drop_mm"), draw("rib_delta_mu")
    inset = draw("rib_inset_mm")
    span_lowest, span_max = draw("rib_span_lowest_deg"), draw("rib_span_max_deg")
    Ar, Br = Ai - inset, Bi - inset
    for k in range(n_ribs):
        z0 = z_rib + k * spacing
        if not (-half_len + 30 < z0 < half_len - 30):
            continue
        # Lowest (floating) ribs are short; the ones above reach round to the front.
        span = np.deg2rad(min(span_lowest + 28.0 * k, span_max))
        for side in (-1.0, 1.0):                          # -1: patient's right (x < 0), +1: left
            start_x = draw("rib_start_x_mm")
            phi0 = math.acos(min(0.99, start_x / Ar))       # posterior end at |x| = start_x, y > 0
            # From the back round the side (|x| = Ar at phi = pi) towards the front (y < 0).
            phis = math.pi - phi0 + np.linspace(0.0, span, max(4, int(span * (Ar + Br) / 2 / 40.0) + 1))
            pts = np.stack([-side * Ar * np.cos(phis), Br * np.sin(phis), z0 - drop * (phis - phis[0]) / span], axis=1)
            # A short neck from the transverse process to the posterior angle of the rib.
            neck = np.array([[spine_x + side * 46.0, spine_y + b_vb + 12.0, z0 + 4.0]])
            pts = np.vstack([neck, pts])
            for a, b in zip(pts[:-1], pts[1:]):
                seg = b - a
                length = float(np.linalg.norm(seg))
                R = _frame_from_axis(seg, [0.0, 0.0, 1.0])
                # Cross-section: thickness along the radial direction (local x), height ~ z (local y).
                local.append(EllipticCylinder((a + b) / 2.0, [rib_t / 2.0, rib_h / 2.0], length / 2.0 + 0.3, R,
                                              mu_rib, "rib"))

    # --- bowel gas ------------------------------------------------------------------------------
    n_gas = draw.integer("gas_pockets")
    lo_r, hi_r = p.gas_semi_axis_mm
    gz = p.gas_z_extent_mm[1]
    for _ in range(n_gas):
        for _attempt in range(50):
            axes = u(lo_r, hi_r, size=3)
            r = float(axes.max())
            fx, fy = draw("gas_region_frac")
            c = np.array([fx * Ai, fy * Bi, tz + u(-gz, gz)])
            R_gas = _rot_z_rad(u(0, np.pi)) @ _rot_y_deg(u(-90, 90))
            if clearance(c) >= r and all(np.linalg.norm(c - c2) >= r + r2 + 1.0 for c2, r2 in gas_balls + avoid):
                local.append(Ellipsoid(c, axes, R_gas, -mu_soft, "bowel gas"))
                gas_balls.append((c, r))
                break

    prims += [q.transformed(T_body) for q in local]
    body_outer = prims[0]

    # --- table and water bath (world frame, horizontal) -----------------------------------------------
    table_top = cy + back_y
    prims.append(_table(draw, table_top, sx + draw("table_shift_x_mm")))
    skin_y = -depth
    meta = {}
    if rng.random() < p.bath_probability:
        prims += _water_bath(draw, body_outer, skin_y, meta)
    meta.update(draw.drawn)
    meta.update(anterior_skin_y_mm=skin_y, table_top_y_mm=table_top, body_center_mm=t_body.tolist(),
                body_yaw_rad=float(np.deg2rad(draw.drawn["body_yaw_deg"])), n_primitives=len(prims))
    return Anatomy(tuple(prims), name="random abdomen", kind="abdomen", meta=meta)


def _water_bath(draw: _Draw, body_outer: Primitive, skin_y: float, meta: dict) -> list[Primitive]:
    """A plastic water bath on the anterior skin: its water fills the box down to the membrane,
    minus the body (so it follows the curved abdomen); its four walls stop at the skin too."""
    bw, bl, bh = draw("bath_width_mm") / 2.0, draw("bath_length_mm") / 2.0, draw("bath_height_mm")
    sink, wall = draw("bath_sink_mm"), draw("bath_wall_mm")
    bx, bz = draw("bath_shift_mm"), draw("bath_shift_mm")
    mu_w, mu_pl = draw("mu_water_per_mm"), draw("mu_plastic_per_mm")
    y_bottom, y_top = skin_y + sink, skin_y - bh
    water = Box([bx, (y_bottom + y_top) / 2.0, bz], [bw, (y_bottom - y_top) / 2.0, bl])
    out: list[Primitive] = [Difference(water, body_outer, mu_per_mm=mu_w, name="water bath")]
    wall_top = y_top - 20.0                     # the walls stand a little above the water
    wall_half_y, wall_cy = (y_bottom - wall_top) / 2.0, (y_bottom + wall_top) / 2.0
    for sgn in (-1.0, 1.0):
        walls = [Box([bx + sgn * (bw + wall / 2.0), wall_cy, bz], [wall / 2.0, wall_half_y, bl + wall]),
                 Box([bx, wall_cy, bz + sgn * (bl + wall / 2.0)], [bw, wall_half_y, wall / 2.0])]
        out += [Difference(w, body_outer, mu_per_mm=mu_pl, name="bath wall") for w in walls]
    meta.update(bath_top_y_mm=y_top, bath_bottom_y_mm=y_bottom, bath_center_mm=[bx, (y_bottom + y_top) / 2.0, bz],
                bath_half_sizes_mm=[bw, (y_bottom - y_top) / 2.0, bl])
    return out


def random_phantom_setup(rng: np.random.Generator, params: PhantomParams | None = None, **overrides) -> Anatomy:
    """The phantom studies' scene (§II-D, Fig. 4A): an agarose phantom in a water tank on the table.

    A ``phantom_edge_mm`` (5 cm) agarose cube, layered with barium when drawn (§II-D.1,
    ~4 mm layers stacked vertically as poured), stands on a plastic block in a degassed water
    tank (plastic walls, open top) on the carbon-fibre table. The phantom centre lies within
    ``phantom_offset_mm`` of the isocentre, where the transducer's focal point is aimed.
    World frame: CBCT, mm, LPS.

    Args:
        rng: the Generator every random draw comes from.
        params: the ranges to draw from; default :class:`PhantomParams`.
        **overrides: fields of :class:`PhantomParams` to replace, a range or a number.
    """
    p = _with_overrides(PhantomParams, params, overrides)
    draw = _Draw(rng, p)
    edge = draw("phantom_edge_mm")
    pc = draw("phantom_offset_mm")
    R_ph = _rot_y_deg(draw("phantom_yaw_deg"))
    mu_w, mu_pl = draw("mu_water_per_mm"), draw("mu_plastic_per_mm")
    stand_h = draw("stand_height_mm")
    floor_y = pc[1] + edge / 2.0 + stand_h           # inner floor of the tank (+y is down)
    W, L, H = draw("tank_inner_width_mm") / 2.0, draw("tank_inner_length_mm") / 2.0, draw("tank_inner_height_mm")
    wall = draw("tank_wall_mm")
    tx, tzc = pc[0] + draw("tank_shift_mm"), pc[2] + draw("tank_shift_mm")
    fill = draw("water_fill")
    water_top = floor_y - fill * H

    prims: list[Primitive] = []
    table_top = floor_y + wall
    prims.append(_table(draw, table_top, tx))
    outer = Box([tx, floor_y - H / 2.0 + wall / 2.0, tzc], [W + wall, (H + wall) / 2.0, L + wall])
    inner_open = Box([tx, floor_y - H / 2.0 - 25.0, tzc], [W, H / 2.0 + 25.0, L])   # open at the top
    prims.append(Difference(outer, inner_open, mu_per_mm=mu_pl, name="tank"))
    prims.append(Box([tx, (floor_y + water_top) / 2.0, tzc], [W, (floor_y - water_top) / 2.0, L],
                     mu_per_mm=mu_w, name="water"))
    sw = draw("stand_half_width_mm")
    prims.append(Box([pc[0], floor_y - stand_h / 2.0, pc[2]], [sw, stand_h / 2.0, sw], R_ph,
                     mu_per_mm=mu_pl - mu_w, name="phantom stand"))
    half = edge / 2.0
    prims.append(Box(pc, [half, half, half], R_ph, mu_per_mm=draw("agarose_delta_mu"), name="agarose phantom"))
    layered = bool(rng.random() < p.layered_probability)
    layer = draw("layer_mm")
    mu_ba = draw("barium_delta_mu")
    if layered:
        # Alternating barium / plain layers, stacked vertically as poured. `y` is the upper (+y,
        # table-side) face of a barium layer in phantom coordinates; the first one starts at a
        # random phase, possibly partly outside the cube (clipped).
        y = half + layer * draw.uniform(0.0, 2.0)
        while y > -half:
            y_hi, y_lo = min(y, half), max(y - layer, -half)
            if y_hi - y_lo > 0.2:
                c_local = np.array([0.0, (y_hi + y_lo) / 2.0, 0.0])
                prims.append(Box(pc + R_ph @ c_local, [half, (y_hi - y_lo) / 2.0, half], R_ph,
                                 mu_per_mm=mu_ba, name="barium layer"))
            y -= 2.0 * layer
    meta = dict(draw.drawn)
    meta.update(layered=layered, phantom_center_mm=pc.tolist(), water_top_y_mm=water_top,
                tank_floor_y_mm=floor_y, table_top_y_mm=table_top, n_primitives=len(prims))
    return Anatomy(tuple(prims), name="random phantom set-up", kind="phantom", meta=meta)


def random_background(rng: np.random.Generator, kind: str = "abdomen") -> Anatomy:
    """A random scene of ``kind``: ``"abdomen"``, ``"phantom"``, or ``"mixed"`` (abdomen with
    probability 156/212, the paper's animal-to-phantom image ratio of §III-A, else phantom)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if kind == "mixed":
        kind = "abdomen" if rng.random() < MIXED_ABDOMEN_PROBABILITY else "phantom"
    if kind == "abdomen":
        return random_abdomen(rng)
    if kind == "phantom":
        return random_phantom_setup(rng)
    raise ValueError(f"kind must be 'abdomen', 'phantom' or 'mixed', got {kind!r}")
