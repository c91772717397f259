"""The pose-estimation cost function of §II-B.3 (eq. 3) and its Jacobian.

.. math::

    C(R, t) = \\sum_a \\sum_{k=1}^{5} \\frac{\\lambda_k}{n_k} \\sum_{i=1}^{n_k}
              \\min_j \\lVert \\hat p_i^{(k)} - s_j^{(k)} \\rVert^2,
    \\qquad \\hat p_i^{(k)} = H(P_a (R p_i^{(k)} + t))

- :class:`DistanceMaps` holds, for one view, the exact Euclidean distance (pixels) from every
  pixel to the nearest segmented pixel of each class — the ``min_j`` of eq. 3, precomputed once
  per segmentation with the Felzenszwalb-Huttenlocher transform the paper cites ([38]; OpenCV's
  ``DIST_L2`` + ``DIST_MASK_PRECISE`` is that algorithm).
- :class:`PoseCost` evaluates eq. 3 by bilinear interpolation of the maps at the projected model
  points (the paper's "distance map texture"), squaring the interpolated distance. A point that
  projects outside the map, or lies behind the X-ray source, gets the paper's constant distance
  of 0.1 px (0.01 px² before normalisation). Classes not segmented in a view contribute nothing in
  that view (see :attr:`PoseCost.weights`).

Conventions: the pose is ``T_carm_transducer`` (4x4) or the 6 parameters ``[rotvec (rad), t (mm)]``
of :func:`histostudy.geometry.transform_from_params`. "Inside the map" is
:meth:`histostudy.imaging.carm.View.in_image`: ``-0.5 <= u < cols - 0.5`` and ``-0.5 <= v < rows - 0.5``
(pixel centres at integer coordinates); in the half-pixel rim outside the outermost pixel centres
the interpolation clamps to the edge (the rim belongs to the edge pixels).

Two back-ends compute the same numbers: fused numba kernels (the default; projection, bilinear
look-up, square and class-weighted sum in one pass over the points, float32 maps and float64
arithmetic and accumulation) and a plain numpy float64 reference (``backend="numpy"``,
:meth:`PoseCost.reference_cost`), which the tests compare against. Sums run over fixed blocks of
points, so a result does not depend on the number of threads (nor on ``parallel``).

Jacobian (for Levenberg-Marquardt, :mod:`histostudy.pose.refine`): the residual of point ``i`` in
view ``a`` is ``r = sqrt(lambda_k / n_k) * d_a(u, v)``, so ``sum r² = C``. Its derivative is taken
for a *left perturbation about the focal point*: ``p' = exp([w]x) (R p) + t + v`` (rotation about
the current transducer origin, i.e. the focal point, then translation), so ``dX/dw = -[R p]x`` and
``dX/dv = I``. The map gradient is the exact gradient of the bilinear interpolant inside the
pixel cell (not interpolated central differences), so the Jacobian is the true derivative of the
residual wherever that is differentiable (finite differences agree, see the tests). Outside
points have a constant residual and a zero Jacobian row.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Mapping, Sequence

import cv2
import numba
import numpy as np

from histostudy.geometry import check_rigid, check_rotation, make_transform, matrix_from_rotvec, transform_from_params
from histostudy.imaging import View
from histostudy.transducer import FEATURE_CLASSES, Feature, LABEL_PRIORITY

__all__ = [
    "OUTSIDE_DISTANCE_PX",
    "PARALLEL_MIN_PROJECTIONS",
    "DistanceMaps",
    "NormalEquations",
    "PoseCost",
    "apply_left_perturbation",
    "euclidean_distance_map",
]

#: The paper's constant distance for points projected outside the distance map (§II-B.3).
OUTSIDE_DISTANCE_PX = 0.1

#: Points per block of the fused kernels: each block sums serially, the blocks in parallel, and the
#: block sums are added in order, so results are bit-identical whatever the thread count.
_BLOCK = 1024

#: Problems of at least this many point projections (blocks x _BLOCK) run on numba's threads
#: when ``PoseCost(parallel=None)``; smaller ones run on the calling thread.
PARALLEL_MIN_PROJECTIONS = 65536

#: Below this squared distance (px²) the distance maps are rounded to exact values (see
#: :func:`euclidean_distance_map`).
_EXACT_SQ_LIMIT = float(2 ** 21)

#: Points per chunk of the numpy reference (bounds its temporaries to a few MB).
_NUMPY_CHUNK = 1 << 15


# --- distance maps ----------------------------------------------------------------------------


def _feature(key, name: str) -> Feature:
    """``key`` as one of the five point classes, or a ValueError naming ``name``."""
    try:
        feature = Feature(int(key))
    except (TypeError, ValueError):
        feature = None
    if feature is None or feature not in FEATURE_CLASSES:
        raise ValueError(
            f"{name} has an unknown class key {key!r}; expected one of "
            f"{[f.name for f in FEATURE_CLASSES]} (histostudy.transducer.Feature, not BACKGROUND)"
        )
    return feature


def _check_view(view, name: str = "view") -> View:
    if not isinstance(view, View):
        raise TypeError(f"{name} must be a histostudy.imaging.carm.View, got {type(view).__name__}")
    rows, cols = view.shape
    if rows < 2 or cols < 2:
        raise ValueError(f"{name} must be at least 2x2 pixels for bilinear interpolation, got shape {view.shape}")
    return view


def euclidean_distance_map(mask: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance (pixels, float32) from every pixel to the nearest True pixel of ``mask``.

    OpenCV's ``distanceTransform(DIST_L2, DIST_MASK_PRECISE)`` — the Felzenszwalb-Huttenlocher
    linear-time transform the paper cites — measures the distance to the nearest *zero* pixel, so
    it is given the complement of the mask. ``mask`` must have at least one True pixel.
    """
    src = np.ascontiguousarray(~mask, dtype=np.uint8)
    d = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64)
    # OpenCV works in float32: d² comes out within ~1.5 ulp (float32) of the exact integer
    # dx² + dy², and those last bits changed between calls on the same mask (they depend on how its
    # threads split the image). Rounding d² to the integer restores the exact distance, bit for
    # bit reproducible, wherever the rounding is unambiguous (d² < 2**21, i.e. d < 1448 px; beyond,
    # OpenCV's value is kept, relative error ~1e-7).
    sq = d * d
    exact = np.sqrt(np.rint(sq))
    return np.where(sq < _EXACT_SQ_LIMIT, exact, d).astype(np.float32)


class DistanceMaps:
    """Distance maps of one view, one per feature class (§II-B.3).

    Args:
        view: the :class:`~histostudy.imaging.carm.View` the segmentation belongs to; its ``shape`` must
            equal the segmentation's.
        segmentation: either a ``(rows, cols)`` integer label image whose values are
            :class:`~histostudy.transducer.Feature` (0 = background; e.g. a U-net's argmax or
            :func:`histostudy.imaging.render.render_labels`), or a dict ``{Feature: (rows, cols) bool}``
            of per-class masks (masks may overlap; a class missing from the dict is absent).
        occlusion_aware: beyond the paper. False (eq. 3 as written): class ``k``'s map is the
            distance to the nearest pixel labelled ``k``. True: the distance to the nearest pixel
            labelled ``k`` *or any class of higher overlap priority* (§II-B.2,
            :data:`~histostudy.transducer.LABEL_PRIORITY`). A label image gives each pixel one
            class, so where a screw, gap or boundary lies over an element the element is not
            labelled there although it is there; with per-class maps its model points are pulled
            towards the nearest visible element pixels. Seen obliquely, the cap's rim bands cover
            wide strips of elements and that pull biased the optimum by about 1 mm on noise-free
            labels (notebook 04 measures both); the occlusion-aware maps remove it. A class that
            is not segmented at all in a view stays absent either way.

    Attributes:
        view: the view.
        maps: ``{Feature: (rows, cols) float32}`` distance in pixels to the nearest pixel of that
            class (with ``occlusion_aware``, of that class or a higher-priority one), for the
            classes present.
        present: the classes with at least one segmented pixel, in enum order.
        absent: the other classes; they carry no information in this view and :class:`PoseCost`
            gives them weight 0 here.
    """

    def __init__(self, view: View, segmentation, *, occlusion_aware: bool = False):
        self.view = _check_view(view)
        if occlusion_aware not in (True, False):
            raise ValueError(f"occlusion_aware must be True or False, got {occlusion_aware!r}")
        self.occlusion_aware = bool(occlusion_aware)
        masks = self._masks(segmentation)
        self.maps: dict[Feature, np.ndarray] = {}
        for feature in FEATURE_CLASSES:
            mask = masks.get(feature)
            if mask is not None and mask.any():
                if occlusion_aware:
                    for higher in LABEL_PRIORITY[:LABEL_PRIORITY.index(feature)]:
                        if higher in masks:
                            mask = mask | masks[higher]
                self.maps[feature] = euclidean_distance_map(mask)
        self.present: tuple[Feature, ...] = tuple(f for f in FEATURE_CLASSES if f in self.maps)
        self.absent: tuple[Feature, ...] = tuple(f for f in FEATURE_CLASSES if f not in self.maps)

    def _masks(self, segmentation) -> dict[Feature, np.ndarray]:
        shape = self.view.shape
        if isinstance(segmentation, Mapping):
            masks = {}
            for key, mask in segmentation.items():
                feature = _feature(key, "segmentation")
                arr = np.asarray(mask)
                if arr.shape != shape:
                    raise ValueError(
                        f"segmentation[{feature.name}] has shape {arr.shape}, but view {self.view.name!r} "
                        f"has shape {shape} (rows, cols)"
                    )
                if arr.dtype != bool:
                    if not np.issubdtype(arr.dtype, np.number) or not np.isin(arr, (0, 1)).all():
                        raise ValueError(f"segmentation[{feature.name}] must be a boolean (or 0/1) mask, "
                                         f"got dtype {arr.dtype}")
                    arr = arr.astype(bool)
                masks[feature] = arr
            return masks
        labels = np.asarray(segmentation)
        if labels.shape != shape:
            raise ValueError(
                f"segmentation (label image) has shape {labels.shape}, but view {self.view.name!r} has "
                f"shape {shape} (rows, cols)"
            )
        if not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(f"segmentation must be an integer label image (values of Feature) or a dict "
                             f"of boolean masks, got dtype {labels.dtype}")
        valid = {int(f) for f in Feature}
        if labels.size and (labels.min() < min(valid) or labels.max() > max(valid)):
            bad = sorted(set(np.unique(labels).tolist()) - valid)
            raise ValueError(f"segmentation holds label values {bad}, expected only Feature values {sorted(valid)}")
        counts = np.bincount(labels.ravel().astype(np.intp), minlength=len(Feature))
        return {f: labels == int(f) for f in FEATURE_CLASSES if counts[int(f)] > 0}

    @property
    def shape(self) -> tuple[int, int]:
        return self.view.shape

    def truncated(self, max_distance_px: float) -> "DistanceMaps":
        """A copy whose distances are capped at ``max_distance_px`` (beyond the paper).

        With it, and the same value as :class:`PoseCost`'s ``outside_distance_px``, a model point
        far from its class, or off the detector, costs a bounded constant: the initialisation's
        searches score poses by how much of the model lands on its features rather than by how
        far the rest is, and a pose with the model off the detector is no longer the cheapest
        (with the paper's 0.1 px it is). For a cost, ``PoseCost(..., max_distance_px=...)`` (or
        :meth:`PoseCost.capped`) gives the same numbers without copying the maps; this copy is for
        looking at the capped maps themselves.
        """
        limit = float(max_distance_px)
        if not np.isfinite(limit) or limit <= 0:
            raise ValueError(f"max_distance_px must be finite and > 0, got {max_distance_px!r}")
        out = copy.copy(self)
        out.maps = {k: np.minimum(v, np.float32(limit)) for k, v in self.maps.items()}
        return out

    def __repr__(self) -> str:
        return (f"DistanceMaps(view={self.view.name!r}, shape={self.shape}, "
                f"present={[f.name for f in self.present]}, absent={[f.name for f in self.absent]})")


# --- fused numba kernels ----------------------------------------------------------------------
#
# Shared arguments:
#   pts (N, 3) f8: model points in the transducer frame, grouped by class (enum order).
#   tasks (n_tasks, 5) i8: rows (view a, class slot s, map start, first point, end point): the
#       points of one class in one view where that class is active, in blocks of <= _BLOCK points.
#       Blocks run in parallel; each writes its own partial sum, added in task order afterwards, so
#       a result is the same bits whatever the number of threads.
#   M (A, 3, 3), c (A, 3) f8: per view, P[:, :3] @ R and P[:, :3] @ t + P[:, 3], so that
#       [u w, v w, w] = M p + c (the pose folded into the projection: 9 mul-adds per point and view).
#   maps (total,) f4: the active distance maps, flattened; rows, cols (A,) i8.
#   wt (A, K) f8 = lambda_k / n_k; outside_sq = 0.1²; cap f8: distances are capped at it (inf: none).
#
# Each block runs in two loops: a branch-free one that projects the points and computes the
# bilinear cell index and fractions (LLVM vectorises it, divisions included), then the look-ups.
# Points outside the map are clamped to a valid cell (so every load is in bounds) and weighted 0.


@numba.njit(inline="always")
def _locate_block(pts, i0, m, M, c, a, base, rows_a, cols_a, cell, fxb, fyb, inb, ub, vb, iwb):
    """Bilinear cell (flat index of its top-left pixel), fractions, inside flag (1.0 / 0.0), u, v and
    1/w of points i0 .. i0+m-1 in view a."""
    m00, m01, m02 = M[a, 0, 0], M[a, 0, 1], M[a, 0, 2]
    m10, m11, m12 = M[a, 1, 0], M[a, 1, 1], M[a, 1, 2]
    m20, m21, m22 = M[a, 2, 0], M[a, 2, 1], M[a, 2, 2]
    c0, c1, c2 = c[a, 0], c[a, 1], c[a, 2]
    u_hi, v_hi = cols_a - 0.5, rows_a - 0.5
    u_cl, v_cl = cols_a - 1.0, rows_a - 1.0
    for j in range(m):
        x = pts[i0 + j, 0]
        y = pts[i0 + j, 1]
        z = pts[i0 + j, 2]
        hw = m20 * x + m21 * y + m22 * z + c2
        iw = 1.0 / hw
        u = (m00 * x + m01 * y + m02 * z + c0) * iw
        v = (m10 * x + m11 * y + m12 * z + c1) * iw
        # View.in_image, and in front of the source; NaN (w == 0) compares False: outside.
        inside = (hw > 0.0) & (u >= -0.5) & (u < u_hi) & (v >= -0.5) & (v < v_hi)
        # Clamp to the outermost pixel centres: the half-pixel rim takes the edge value (NaN -> 0).
        uc = u if u > 0.0 else 0.0
        uc = uc if uc < u_cl else u_cl
        vc = v if v > 0.0 else 0.0
        vc = vc if vc < v_cl else v_cl
        x0 = min(int(uc), cols_a - 2)
        y0 = min(int(vc), rows_a - 2)
        cell[j] = base + y0 * cols_a + x0
        fxb[j] = uc - x0
        fyb[j] = vc - y0
        inb[j] = 1.0 if inside else 0.0
        ub[j] = u
        vb[j] = v
        iwb[j] = iw


@numba.njit(inline="always")
def _interpolate(maps, cell, stride, fx, fy, cap):
    """Bilinear distance and its exact gradient inside the cell, (d, dd/dfx, dd/dfy), of the map
    capped at ``cap`` pixels (each corner is capped before interpolating, as in
    :meth:`DistanceMaps.truncated`; ``inf`` for no cap)."""
    # Unsigned indices spare numba's negative-index wrap-around test on each load.
    i00 = np.uint64(cell)
    one = np.uint64(1)
    su = np.uint64(stride)
    d00 = min(np.float64(maps[i00]), cap)
    d10 = min(np.float64(maps[i00 + one]), cap)
    d01 = min(np.float64(maps[i00 + su]), cap)
    d11 = min(np.float64(maps[i00 + su + one]), cap)
    top = d00 + fx * (d10 - d00)
    bottom = d01 + fx * (d11 - d01)
    return top + fy * (bottom - top), (1.0 - fy) * (d10 - d00) + fy * (d11 - d01), bottom - top


@numba.njit(fastmath=False, cache=True)
def _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    """Eq. 3's contribution of one task (one block of one class in one view)."""
    a, s, base, i0, i1 = tasks[ti, 0], tasks[ti, 1], tasks[ti, 2], tasks[ti, 3], tasks[ti, 4]
    m = i1 - i0
    cell = np.empty(_BLOCK, dtype=np.int64)
    fxb = np.empty(_BLOCK)
    fyb = np.empty(_BLOCK)
    inb = np.empty(_BLOCK)
    ub = np.empty(_BLOCK)
    vb = np.empty(_BLOCK)
    iwb = np.empty(_BLOCK)
    _locate_block(pts, i0, m, M, c, a, base, rows[a], cols[a], cell, fxb, fyb, inb, ub, vb, iwb)
    total = 0.0
    n_out = 0.0
    for j in range(m):
        d, gu, gv = _interpolate(maps, cell[j], cols[a], fxb[j], fyb[j], cap)
        total += inb[j] * (d * d)
        n_out += 1.0 - inb[j]
    return wt[a, s] * (total + n_out * outside_sq)


@numba.njit(parallel=True, fastmath=False, cache=True)
def _cost_parallel(pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    partial = np.zeros(tasks.shape[0])
    for ti in numba.prange(tasks.shape[0]):
        partial[ti] = _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap)
    out = 0.0
    for ti in range(tasks.shape[0]):
        out += partial[ti]
    return out


@numba.njit(fastmath=False, cache=True)
def _cost_serial(pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    out = 0.0
    for ti in range(tasks.shape[0]):
        out += _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap)
    return out


@numba.njit(parallel=True, fastmath=False, cache=True)
def _costs_batch(pts, tasks, M, c_all, maps, rows, cols, wt, outside_sq, cap):
    """:func:`_cost_serial` at each of the translations folded into ``c_all`` (n, A, 3), in parallel
    over them; each is summed in task order, the same bits as one call per pose."""
    n = c_all.shape[0]
    out = np.empty(n)
    for k in numba.prange(n):
        total = 0.0
        for ti in range(tasks.shape[0]):
            total += _task_cost(ti, pts, tasks, M, c_all[k], maps, rows, cols, wt, outside_sq, cap)
        out[k] = total
    return out


@numba.njit(inline="always")
def _jacobian_row(R, P3, a, x, y, z, u, v, iw, gu, gv, sw, jrow):
    """``jrow = sw * dd/d[w, v]`` for one point: ``[q x g, g]`` with ``q = R p`` and ``g = dd/dX``.

    ``dd/dX = (gu (P0 - u P2) + gv (P1 - v P2)) / w`` with ``P0..P2`` the rows of the view's 3x3;
    a left rotation moves the world point by ``w x q``, hence ``dd/dw = q x g``.
    """
    qx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
    qy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
    qz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
    s_ = sw * iw
    gx = s_ * (gu * (P3[a, 0, 0] - u * P3[a, 2, 0]) + gv * (P3[a, 1, 0] - v * P3[a, 2, 0]))
    gy = s_ * (gu * (P3[a, 0, 1] - u * P3[a, 2, 1]) + gv * (P3[a, 1, 1] - v * P3[a, 2, 1]))
    gz = s_ * (gu * (P3[a, 0, 2] - u * P3[a, 2, 2]) + gv * (P3[a, 1, 2] - v * P3[a, 2, 2]))
    jrow[0] = qy * gz - qz * gy
    jrow[1] = qz * gx - qx * gz
    jrow[2] = qx * gy - qy * gx
    jrow[3] = gx
    jrow[4] = gy
    jrow[5] = gz


@numba.njit(inline="always")
def _map_gradient(maps, cell, cols_a, rows_a, fx, fy, u, v, cap):
    """Distance and its gradient in pixels (d, dd/du, dd/dv); 0 across a clamped (rim) direction."""
    d, gu, gv = _interpolate(maps, cell, cols_a, fx, fy, cap)
    if not (u >= 0.0 and u <= cols_a - 1.0):
        gu = 0.0
    if not (v >= 0.0 and v <= rows_a - 1.0):
        gv = 0.0
    return d, gu, gv


@numba.njit(fastmath=False, cache=True)
def _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, out):
    """Cost, J^T J (upper triangle, 21) and J^T r (6) of one task into ``out`` (28,)."""
    a, s, base, i0, i1 = tasks[ti, 0], tasks[ti, 1], tasks[ti, 2], tasks[ti, 3], tasks[ti, 4]
    m = i1 - i0
    cell = np.empty(_BLOCK, dtype=np.int64)
    fxb = np.empty(_BLOCK)
    fyb = np.empty(_BLOCK)
    inb = np.empty(_BLOCK)
    ub = np.empty(_BLOCK)
    vb = np.empty(_BLOCK)
    iwb = np.empty(_BLOCK)
    _locate_block(pts, i0, m, M, c, a, base, rows[a], cols[a], cell, fxb, fyb, inb, ub, vb, iwb)
    acc = np.zeros(28)
    jrow = np.zeros(6)
    sw = np.sqrt(wt[a, s])
    n_out = 0.0
    for j in range(m):
        if inb[j] == 0.0:
            n_out += 1.0
            continue
        u, v = ub[j], vb[j]
        d, gu, gv = _map_gradient(maps, cell[j], cols[a], rows[a], fxb[j], fyb[j], u, v, cap)
        r = sw * d
        acc[0] += r * r
        i = i0 + j
        _jacobian_row(R, P3, a, pts[i, 0], pts[i, 1], pts[i, 2], u, v, iwb[j], gu, gv, sw, jrow)
        idx = 1
        for p in range(6):
            jp = jrow[p]
            for q in range(p, 6):
                acc[idx] += jp * jrow[q]
                idx += 1
        for p in range(6):
            acc[22 + p] += jrow[p] * r
    acc[0] += wt[a, s] * n_out * outside_sq
    for idx in range(28):
        out[idx] = acc[idx]


@numba.njit(parallel=True, fastmath=False, cache=True)
def _normal_parallel(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap):
    """Cost, J^T J and J^T r in one pass; J (n x 6) is never built. Returns the 28 sums."""
    partial = np.zeros((tasks.shape[0], 28))
    for ti in numba.prange(tasks.shape[0]):
        _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, partial[ti])
    total = np.zeros(28)
    for ti in range(tasks.shape[0]):
        for idx in range(28):
            total[idx] += partial[ti, idx]
    return total


@numba.njit(fastmath=False, cache=True)
def _normal_serial(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap):
    part = np.zeros(28)
    total = np.zeros(28)
    for ti in range(tasks.shape[0]):
        _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, part)
        for idx in range(28):
            total[idx] += part[idx]
    return total


@numba.njit(fastmath=False, cache=True)
def _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    """Residuals and Jacobian rows of one task into ``r_out (A, N)`` and ``j_out (A, N, 6)``."""
    a, s, base, i0, i1 = tasks[ti, 0], tasks[ti, 1], tasks[ti, 2], tasks[ti, 3], tasks[ti, 4]
    m = i1 - i0
    cell = np.empty(_BLOCK, dtype=np.int64)
    fxb = np.empty(_BLOCK)
    fyb = np.empty(_BLOCK)
    inb = np.empty(_BLOCK)
    ub = np.empty(_BLOCK)
    vb = np.empty(_BLOCK)
    iwb = np.empty(_BLOCK)
    _locate_block(pts, i0, m, M, c, a, base, rows[a], cols[a], cell, fxb, fyb, inb, ub, vb, iwb)
    jrow = np.zeros(6)
    sw = np.sqrt(wt[a, s])
    for j in range(m):
        i = i0 + j
        if inb[j] == 0.0:
            r_out[a, i] = sw * outside
            continue
        u, v = ub[j], vb[j]
        d, gu, gv = _map_gradient(maps, cell[j], cols[a], rows[a], fxb[j], fyb[j], u, v, cap)
        r_out[a, i] = sw * d
        _jacobian_row(R, P3, a, pts[i, 0], pts[i, 1], pts[i, 2], u, v, iwb[j], gu, gv, sw, jrow)
        for p in range(6):
            j_out[a, i, p] = jrow[p]


@numba.njit(parallel=True, fastmath=False, cache=True)
def _residual_parallel(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    """Residuals and Jacobian rows of the active (view, class) pairs; the caller zeroes both
    outputs beforehand (inactive pairs stay 0)."""
    for ti in numba.prange(tasks.shape[0]):
        _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out)


@numba.njit(fastmath=False, cache=True)
def _residual_serial(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    for ti in range(tasks.shape[0]):
        _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out)


# --- the cost -------------------------------------------------------------------------------


@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton quantities at one pose (left perturbation ``[w (rad), v (mm)]`` about the focal point).

    ``cost`` = C (eq. 3) = ``sum r²``; ``JtJ`` (6, 6) and ``Jtr`` (6,) with ``J = dr/d[w, v]``.
    The gradient of C is ``2 Jtr``.
    """

    cost: float
    JtJ: np.ndarray
    Jtr: np.ndarray


def apply_left_perturbation(T, delta) -> np.ndarray:
    """``T'`` with ``R' = exp([w]x) R`` and ``t' = t + v`` for ``delta = [w (rad), v (mm)]``.

    The rotation turns the transducer about its own origin (the focal point) in world axes, so
    rotation and translation steps do not mix; this is the perturbation the Jacobians of
    :class:`PoseCost` are taken with.
    """
    T = np.asarray(T, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64).reshape(-1)
    if d.shape != (6,) or not np.all(np.isfinite(d)):
        raise ValueError(f"delta must be 6 finite numbers [w (rad), v (mm)], got {delta!r}")
    out = np.eye(4)
    out[:3, :3] = matrix_from_rotvec(d[:3]) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + d[3:]
    return out


class PoseCost:
    """Eq. 3 over one or more views, for a fixed model and fixed segmentations (§II-B.3).

    Args:
        points: ``{Feature: (n, 3)}`` model points in mm in the transducer frame (e.g.
            ``TransducerModel.build(spacing_mm=0.47).points``); empty classes are skipped.
        maps: one :class:`DistanceMaps` per view.
        class_weights: ``{Feature: lambda_k >= 0}``; default 1 for every class (the paper does not
            give its values). Classes left out of the dict weigh 1.
        outside_distance_px: the constant distance for points outside the map or behind the
            source (paper: 0.1 px).
        max_distance_px: beyond the paper: cap every map distance at this many pixels (None: eq. 3
            as written). The same numbers, bit for bit, as the cost on
            :meth:`DistanceMaps.truncated` maps, but applied as the kernels read the maps, so the
            ~50 MB of maps of a biplane pair are not copied for each cap (see :meth:`capped`).
        backend: ``"numba"`` (fused kernels, the default) or ``"numpy"`` (the float64 reference).
        parallel: run the numba kernels on numba's threads (True), on the calling thread (False),
            or decide by size (None: threads from :data:`PARALLEL_MIN_PROJECTIONS` projections on).
            Both give the same bits. Threads pay a start-up per call (tens of µs on an idle
            machine, but a scheduler time slice, ~5-8 ms, when another process holds a core), so
            small costs (subsets, grid searches) run serially; force False on a shared machine.

    Attributes:
        classes: the classes with points, in enum order (the "slots" of :attr:`weights`).
        n_points: ``{Feature: n_k}``.
        weights: ``(n_views, n_classes)`` float64 ``lambda_k / n_k``, 0 where the class is absent
            from that view's segmentation (it then contributes nothing there).
        active: ``(n_views, n_classes)`` bool, the classes that contribute in each view.

    Call it with a 4x4 ``T_carm_transducer`` or 6 parameters ``[rotvec (rad), t (mm)]``.
    """

    def __init__(self, points: Mapping, maps: Sequence[DistanceMaps], *,
                 class_weights: Mapping | None = None, outside_distance_px: float = OUTSIDE_DISTANCE_PX,
                 max_distance_px: float | None = None, backend: str = "numba", parallel: bool | None = None,
                 _buffer=None):
        if not isinstance(points, Mapping):
            raise TypeError(f"points must be a dict {{Feature: (n, 3) array}}, got {type(points).__name__}")
        pts = {}
        for key, value in points.items():
            feature = _feature(key, "points")
            arr = np.asarray(value, dtype=np.float64)
            if arr.size == 0:
                continue
            if arr.ndim != 2 or arr.shape[1] != 3 or not np.all(np.isfinite(arr)):
                raise ValueError(f"points[{feature.name}] must be a finite (n, 3) array in mm, got shape {arr.shape}")
            pts[feature] = arr
        if not pts:
            raise ValueError("points holds no points in any class; eq. 3 needs a model")
        maps = list(maps) if not isinstance(maps, DistanceMaps) else [maps]
        if not maps:
            raise ValueError("maps must hold at least one DistanceMaps (one per view), got none")
        for i, m in enumerate(maps):
            if not isinstance(m, DistanceMaps):
                raise TypeError(f"maps[{i}] must be a DistanceMaps, got {type(m).__name__}")
        lam = {f: 1.0 for f in FEATURE_CLASSES}
        for key, value in (class_weights or {}).items():
            feature = _feature(key, "class_weights")
            value = float(value)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"class_weights[{feature.name}] must be finite and >= 0, got {value!r}")
            lam[feature] = value
        outside = float(outside_distance_px)
        if not np.isfinite(outside) or outside < 0:
            raise ValueError(f"outside_distance_px must be finite and >= 0, got {outside_distance_px!r}")
        if max_distance_px is not None:
            number = isinstance(max_distance_px, (int, float, np.integer, np.floating))
            if isinstance(max_distance_px, bool) or not number or not np.isfinite(max_distance_px) \
                    or max_distance_px <= 0:
                raise ValueError(f"max_distance_px must be None or a finite number > 0 (pixels), "
                                 f"got {max_distance_px!r}")
            max_distance_px = float(max_distance_px)
        if backend not in ("numba", "numpy"):
            raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
        if parallel not in (None, True, False):
            raise ValueError(f"parallel must be None (automatic), True or False, got {parallel!r}")

        self.classes: tuple[Feature, ...] = tuple(f for f in FEATURE_CLASSES if f in pts)
        self.n_points = {f: len(pts[f]) for f in self.classes}
        self.points = {f: pts[f] for f in self.classes}
        self.maps = maps
        self.views = [m.view for m in maps]
        self.class_weights = {f: lam[f] for f in self.classes}
        self.outside_distance_px = outside
        self.max_distance_px = max_distance_px
        # The maps are float32: capping them at the float32 value of the cap is what
        # DistanceMaps.truncated does, so the kernels compare against the same number.
        self._cap = np.inf if max_distance_px is None else float(np.float32(max_distance_px))
        self.backend = backend
        self.parallel = parallel

        n_views, n_classes = len(maps), len(self.classes)
        self.active = np.array([[f in m.maps and lam[f] > 0 for f in self.classes] for m in maps], dtype=bool)
        if not self.active.any():
            raise ValueError(
                "no class is both in the model (with weight > 0) and segmented in any view: the cost "
                f"would be constant. Model classes {[f.name for f in self.classes]}, segmented: "
                f"{[[f.name for f in m.present] for m in maps]}"
            )
        self.weights = np.array([[lam[f] / self.n_points[f] for f in self.classes]] * n_views) * self.active

        # Pose-independent data, laid out once for the kernels.
        self._pts = np.ascontiguousarray(np.vstack([pts[f] for f in self.classes]))
        self._P = np.stack([v.P for v in self.views])  # (A, 3, 4)
        self._P3 = np.ascontiguousarray(self._P[:, :, :3])
        self._rows = np.array([v.shape[0] for v in self.views], dtype=np.int64)
        self._cols = np.array([v.shape[1] for v in self.views], dtype=np.int64)
        if _buffer is not None and _buffer[1].shape == self.active.shape and np.all((_buffer[1] >= 0) == self.active):
            self._maps, self._map_start = _buffer
        else:
            self._map_start = np.full((n_views, n_classes), -1, dtype=np.int64)
            chunks, pos = [], 0
            for a, m in enumerate(maps):
                for s, f in enumerate(self.classes):
                    if self.active[a, s]:
                        self._map_start[a, s] = pos
                        chunks.append(m.maps[f].ravel())
                        pos += m.maps[f].size
            self._maps = np.ascontiguousarray(np.concatenate(chunks), dtype=np.float32)
        # The kernels' work list: (view, class slot, map start, first point, end point) blocks.
        first = np.concatenate([[0], np.cumsum([self.n_points[f] for f in self.classes])])
        tasks = [(a, s, self._map_start[a, s], i0, min(i0 + _BLOCK, first[s + 1]))
                 for a in range(n_views) for s in range(n_classes) if self.active[a, s]
                 for i0 in range(first[s], first[s + 1], _BLOCK)]
        self._tasks = np.array(tasks, dtype=np.int64).reshape(-1, 5)

    # --- derived costs ----------------------------------------------------------------------

    def _use_threads(self) -> bool:
        if self.parallel is None:
            return numba.get_num_threads() > 1 and len(self._tasks) * _BLOCK >= PARALLEL_MIN_PROJECTIONS
        return self.parallel

    def _derive(self, points: dict, maps: list, view_indices=None) -> "PoseCost":
        # Same maps and classes: share the flattened map buffer instead of copying ~50 MB again.
        shared = (self._maps, self._map_start) if maps is self.maps else None
        if view_indices is not None and len(view_indices) == 1 and self.active[view_indices[0]].any():
            # One view's maps are one contiguous stretch of the buffer: a view, not a copy.
            a = view_indices[0]
            starts = self._map_start[a]
            first = starts[self.active[a]].min()
            end = max(starts[s] + self.maps[a].maps[f].size for s, f in enumerate(self.classes) if self.active[a, s])
            shared = (self._maps[first:end], np.where(self.active[a], starts - first, -1)[None, :])
        return PoseCost(points, maps, class_weights=self.class_weights,
                        outside_distance_px=self.outside_distance_px, max_distance_px=self.max_distance_px,
                        backend=self.backend, parallel=self.parallel, _buffer=shared)

    def with_outside_distance(self, outside_distance_px: float) -> "PoseCost":
        """The same cost with another constant distance for points off the map (eq. 3's 0.1 px);
        the distance maps are shared, not copied."""
        return self.capped(self.max_distance_px, outside_distance_px)

    def capped(self, max_distance_px: float | None, outside_distance_px: float | None = None) -> "PoseCost":
        """The same points and maps with the distances capped at ``max_distance_px`` (None: no cap)
        and, if given, another constant for points off the map; the maps are shared, not copied.

        A cap bounds what a model point on a missed or spurious feature can add, so a few of them
        cannot pull the pose (beyond the paper; :func:`histostudy.pose.estimate_pose` caps its
        searches, refinement and verdict). Asked for what it already is, the cost returns itself."""
        outside = self.outside_distance_px if outside_distance_px is None else outside_distance_px
        if max_distance_px == self.max_distance_px and outside == self.outside_distance_px:
            return self
        return PoseCost(self.points, self.maps, class_weights=self.class_weights, outside_distance_px=outside,
                        max_distance_px=max_distance_px, backend=self.backend, parallel=self.parallel,
                        _buffer=(self._maps, self._map_start))

    def subset(self, n_per_class: int, rng: np.random.Generator) -> "PoseCost":
        """A cheaper cost on at most ``n_per_class`` points of each class, drawn without replacement.

        The normalisation by ``n_k`` makes it an unbiased estimate of the full cost's per-class
        means, so it can stand in for it in a coarse first pass (grid search, coarse-to-fine LM).
        The distance maps are shared, not recomputed.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        n = int(n_per_class)
        if n != n_per_class or n < 1:
            raise ValueError(f"n_per_class must be a positive integer, got {n_per_class!r}")
        sub = {}
        for f in self.classes:
            p = self.points[f]
            sub[f] = p if len(p) <= n else p[np.sort(rng.choice(len(p), size=n, replace=False))]
        return self._derive(sub, self.maps)

    def select_views(self, indices) -> "PoseCost":
        """The cost over a subset of the views (e.g. one view for the per-plane grid search, §II-B.4)."""
        idx = [indices] if np.isscalar(indices) else list(indices)
        for i in idx:
            if not (isinstance(i, (int, np.integer)) and 0 <= i < len(self.maps)):
                raise ValueError(f"indices must be view indices in [0, {len(self.maps)}), got {indices!r}")
        return self._derive(self.points, [self.maps[i] for i in idx], view_indices=idx)

    # --- evaluation -------------------------------------------------------------------------

    def _pose(self, pose) -> np.ndarray:
        arr = np.asarray(pose, dtype=np.float64)
        if arr.shape == (4, 4):
            return check_rigid(arr, "pose")
        if arr.size == 6 and arr.ndim == 1:
            return transform_from_params(arr)
        raise ValueError(f"pose must be a 4x4 T_carm_transducer or 6 parameters [rotvec (rad), t (mm)], "
                         f"got shape {arr.shape}")

    def _folded(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per view ``M = P3 R`` and ``c = P3 t + P[:, 3]``: ``[u w, v w, w] = M p + c``."""
        R, t = T[:3, :3], T[:3, 3]
        M = np.ascontiguousarray(self._P3 @ R)
        c = np.ascontiguousarray(self._P3 @ t + self._P[:, :, 3])
        return M, c

    def __call__(self, pose) -> float:
        """C (eq. 3) at ``pose`` (4x4 or 6 parameters)."""
        T = self._pose(pose)
        if self.backend == "numpy":
            return float(self._reference_terms(T).sum())
        M, c = self._folded(T)
        kernel = _cost_parallel if self._use_threads() else _cost_serial
        return float(kernel(self._pts, self._tasks, M, c, self._maps, self._rows, self._cols, self.weights,
                            self.outside_distance_px ** 2, self._cap))

    def costs_at_translations(self, R, translations_mm) -> np.ndarray:
        """C (eq. 3) at the poses ``(R, t)`` for each row ``t`` of ``translations_mm`` (n, 3): a grid
        search's nodes in one call, the rotation checked and folded into the projections once."""
        R = check_rotation(R, "R")
        t = np.asarray(translations_mm, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(t)):
            raise ValueError("translations_mm must be finite (n, 3) mm")
        if self.backend == "numpy" or len(t) == 0:
            return np.array([self(make_transform(R, ti)) for ti in t], dtype=np.float64)
        M = np.ascontiguousarray(self._P3 @ R)
        # Folded exactly as :meth:`_folded` does, so that each cost is the bits of a single call.
        c_all = np.ascontiguousarray([self._P3 @ ti + self._P[:, :, 3] for ti in t]).reshape(len(t), -1, 3)
        return _costs_batch(self._pts, self._tasks, M, c_all, self._maps, self._rows, self._cols, self.weights,
                            self.outside_distance_px ** 2, self._cap)

    def reference_cost(self, pose) -> float:
        """C (eq. 3) by the plain numpy float64 reference, whatever the backend."""
        return float(self._reference_terms(self._pose(pose)).sum())

    def terms(self, pose) -> np.ndarray:
        """``(n_views, n_classes)`` contributions ``lambda_k / n_k * sum_i d²`` (numpy reference); they sum to C."""
        return self._reference_terms(self._pose(pose))

    def _reference_distances(self, T: np.ndarray, a: int, s: int, pts: np.ndarray,
                             jacobian: bool = False):
        """Numpy float64 reference for view ``a``, class slot ``s``: interpolated distances ``d``
        (the outside constant where a point is outside) and, with ``jacobian``, ``dd/d[w, v]`` (n, 6)."""
        view = self.views[a]
        rows, cols = view.shape
        q = pts @ T[:3, :3].T
        uvw = (q + T[:3, 3]) @ self._P3[a].T + self._P[a, :, 3]
        hw = uvw[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = uvw[:, 0] / hw, uvw[:, 1] / hw
        inside = (hw > 0) & (u >= -0.5) & (u < cols - 0.5) & (v >= -0.5) & (v < rows - 0.5)
        d = np.full(len(pts), self.outside_distance_px)
        ui, vi = u[inside], v[inside]
        uc = np.clip(ui, 0.0, cols - 1.0)
        vc = np.clip(vi, 0.0, rows - 1.0)
        x0 = np.minimum(uc.astype(np.int64), cols - 2)
        y0 = np.minimum(vc.astype(np.int64), rows - 2)
        fx, fy = uc - x0, vc - y0
        dmap = self.maps[a].maps[self.classes[s]]
        d00 = np.minimum(dmap[y0, x0].astype(np.float64), self._cap)
        d10 = np.minimum(dmap[y0, x0 + 1].astype(np.float64), self._cap)
        d01 = np.minimum(dmap[y0 + 1, x0].astype(np.float64), self._cap)
        d11 = np.minimum(dmap[y0 + 1, x0 + 1].astype(np.float64), self._cap)
        top = d00 + fx * (d10 - d00)
        bottom = d01 + fx * (d11 - d01)
        d[inside] = top + fy * (bottom - top)
        if not jacobian:
            return d
        gu = np.where(ui == uc, (1 - fy) * (d10 - d00) + fy * (d11 - d01), 0.0)
        gv = np.where(vi == vc, bottom - top, 0.0)
        P3 = self._P3[a]
        g = ((gu[:, None] * (P3[0] - ui[:, None] * P3[2]) + gv[:, None] * (P3[1] - vi[:, None] * P3[2]))
             / hw[inside, None])
        J = np.zeros((len(pts), 6))
        J[inside, :3] = np.cross(q[inside], g)
        J[inside, 3:] = g
        return d, J

    def _reference_terms(self, T: np.ndarray) -> np.ndarray:
        out = np.zeros(self.weights.shape)
        for a in range(len(self.maps)):
            for s, f in enumerate(self.classes):
                if not self.active[a, s]:
                    continue
                pts = self.points[f]
                total = 0.0
                for start in range(0, len(pts), _NUMPY_CHUNK):
                    d = self._reference_distances(T, a, s, pts[start:start + _NUMPY_CHUNK])
                    total += float(np.dot(d, d))
                out[a, s] = self.weights[a, s] * total
        return out

    def residuals(self, pose) -> np.ndarray:
        """``(n_views * N,)`` weighted residuals ``sqrt(lambda_k / n_k) d`` (numpy reference), view-major,
        points in the order of :attr:`classes`; ``sum r² = C``."""
        return self.reference_residuals_and_jacobian(pose, jacobian=False)[0]

    def reference_residuals_and_jacobian(self, pose, jacobian: bool = True):
        """Numpy float64 reference of :meth:`residuals_and_jacobian` (``J`` is None without ``jacobian``)."""
        T = self._pose(pose)
        rs, Js = [], []
        for a in range(len(self.maps)):
            for s, f in enumerate(self.classes):
                n = self.n_points[f]
                if not self.active[a, s]:
                    rs.append(np.zeros(n))
                    Js.append(np.zeros((n, 6)))
                    continue
                sw = np.sqrt(self.weights[a, s])
                out = self._reference_distances(T, a, s, self.points[f], jacobian=jacobian)
                d, J = out if jacobian else (out, None)
                rs.append(sw * d)
                Js.append(None if J is None else sw * J)
        return np.concatenate(rs), (np.vstack(Js) if jacobian else None)

    def residuals_and_jacobian(self, pose) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``r`` ``(n_views * N,)`` and their Jacobian ``(n_views * N, 6)`` with respect to the
        left perturbation ``[w (rad), v (mm)]`` about the focal point (module docstring).

        ``r = sqrt(lambda_k / n_k) * d`` view-major, points in the order of :attr:`classes`
        (``sum r² = C``; outside points carry the constant and a zero row; absent classes 0).
        Materialises the n x 6 Jacobian (fused numba kernel, or the numpy reference with
        ``backend="numpy"``); the refinement uses :meth:`normal_equations`, which does not.
        """
        T = self._pose(pose)
        if self.backend == "numpy":
            return self.reference_residuals_and_jacobian(T)
        M, c = self._folded(T)
        n_views, n = len(self.maps), len(self._pts)
        r = np.zeros((n_views, n))
        J = np.zeros((n_views, n, 6))
        kernel = _residual_parallel if self._use_threads() else _residual_serial
        kernel(self._pts, self._tasks, np.ascontiguousarray(T[:3, :3]), M, c, self._P3, self._maps,
               self._rows, self._cols, self.weights, self.outside_distance_px, self._cap, r, J)
        return r.reshape(-1), J.reshape(-1, 6)

    def normal_equations(self, pose) -> NormalEquations:
        """C, ``J^T J`` and ``J^T r`` at ``pose`` in one fused pass (nothing of size n x 6 is built).

        With ``backend="numpy"`` they are formed from the materialised reference Jacobian.
        """
        T = self._pose(pose)
        if self.backend == "numpy":
            r, J = self.reference_residuals_and_jacobian(T)
            return NormalEquations(float(r @ r), J.T @ J, J.T @ r)
        M, c = self._folded(T)
        kernel = _normal_parallel if self._use_threads() else _normal_serial
        acc = kernel(self._pts, self._tasks, np.ascontiguousarray(T[:3, :3]), M, c, self._P3, self._maps,
                     self._rows, self._cols, self.weights, self.outside_distance_px ** 2, self._cap)
        JtJ = np.zeros((6, 6))
        JtJ[np.triu_indices(6)] = acc[1:22]
        JtJ = JtJ + np.triu(JtJ, 1).T
        return NormalEquations(float(acc[0]), JtJ, acc[22:28].copy())

    @property
    def n_total(self) -> int:
        """Number of model points (all classes)."""
        return len(self._pts)

    def __repr__(self) -> str:
        counts = ", ".join(f"{f.name}={n}" for f, n in self.n_points.items())
        cap = "" if self.max_distance_px is None else f", max_distance_px={self.max_distance_px:g}"
        return f"PoseCost({len(self.maps)} views, {counts}{cap}, backend={self.backend!r})"
