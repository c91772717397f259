"""Bundles of X-ray rays from one origin and the linear and quadratic forms in the unit direction that the
analytic shapes share to compute exact chords (§II-B.2). World frame (CBCT, LPS), mm."""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


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

    def sub(self, index) -> _Rays:
        """The rays at ``index`` (a tuple of slices) of these, sharing the products."""
        dx, dy, dz = (c[index] for c in self.d)
        return _Rays(dx, dy, dz, parent=self, index=index)

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
