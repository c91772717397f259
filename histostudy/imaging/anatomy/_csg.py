"""Composite solids (§II-B.2, §II-D): the intersection and the difference of convex analytic shapes, their
chords exact (a body flattened against the table, a bath pressed onto the abdomen). World frame: CBCT,
LPS, mm; ``mu_per_mm`` in 1/mm, a difference to the surroundings."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ._rays import _chord_from_interval
from ._shapes import Primitive, _mu

__all__ = [
    "Difference",
    "Intersection",
]


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
