"""A synthetic X-ray scene and its line-integral image in a C-arm view (§II-B.2, eq. 1-2): the
:class:`Anatomy` of analytic solids, a user's own projection (:class:`StaticBackground`), and the
:class:`Background` both are to the renderer. World frame: CBCT, LPS, mm; images ``(rows, cols)`` float32."""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from histostudy.geometry import as_points, check_rigid

from ..carm import View
from ._rays import _Rays
from ._shapes import Primitive

__all__ = [
    "Anatomy",
    "Background",
    "StaticBackground",
]

# Rows per work unit of the renderer: ~40k rays per band keeps the temporaries of one primitive in
# the CPU cache, and bands are what the worker threads share out. Fixed (not tied to the number of
# workers) so the image is bit-identical for any ``workers``.
_BAND_ROWS = 32


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

    def transformed(self, T) -> Anatomy:
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
