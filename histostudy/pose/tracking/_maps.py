"""Distance maps of a tracking region (§II-B.3), written into buffers reused frame after frame
(:class:`RegionMaps`): the values of :class:`~histostudy.pose.distance_maps.DistanceMaps`, exact up to
an optional reach. Maps ``(rows, cols)`` float32 in the region view's pixels (docs/tracking.md).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from histostudy.imaging import View
from histostudy.transducer import FEATURE_CLASSES, LABEL_PRIORITY, Feature

from ..distance_maps import DistanceMaps, euclidean_distance_map

__all__ = ["RegionMaps"]

#: Regions with ``rows² + cols²`` below this are rounded in float32 (every ``d² < 2**20``).
_FLOAT32_DIAGONAL_SQ = float(2 ** 20)


def _lookup_tables(occlusion_aware: bool) -> dict[Feature, np.ndarray]:
    """Per class, a 256-entry uint8 table: 0 for the label values the class's map measures to, 1 else."""
    tables = {}
    for feature in FEATURE_CLASSES:
        table = np.ones(256, np.uint8)
        table[int(feature)] = 0
        if occlusion_aware:
            for higher in LABEL_PRIORITY[:LABEL_PRIORITY.index(feature)]:
                table[int(higher)] = 0
        tables[feature] = table
    return tables


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _bounded_distance(src, reach_px, out):
    """The exact Euclidean distance from each pixel to the nearest zero of ``src`` (uint8) where it is
    at most ``reach_px``, and ``reach_px`` (float32) where it is farther (or there is no zero), into
    ``out`` (float32, src's shape): the separable transform (a column pass, then a row pass) with
    every search cut at ``reach_px``, so its cost grows with the reach and not with the image."""
    rows, cols = src.shape
    r = int(np.floor(reach_px))
    far = r + 1  # a column distance past the reach: exact ones up to r are all the row pass needs
    limit_sq = np.float64(reach_px) * np.float64(reach_px)
    column = np.empty((rows, cols), np.int32)
    # Rows and shifted rows are taken as slices: indices that cannot be negative let LLVM vectorise
    # the loops over a row.
    first, src_row = column[0], src[0]
    for x in range(cols):
        first[x] = 0 if src_row[x] == 0 else far
    for y in range(1, rows):
        prev, row, src_row = column[y - 1], column[y], src[y]
        for x in range(cols):
            below = prev[x] + 1
            row[x] = 0 if src_row[x] == 0 else (below if below < far else far)
    for y in range(rows - 2, -1, -1):
        nxt, row = column[y + 1], column[y]
        for x in range(cols):
            above = nxt[x] + 1
            row[x] = above if above < row[x] else row[x]
    squared = np.empty(cols + 2 * r, np.int32)
    best = np.empty(cols, np.int32)
    big = np.int32(2 * far * far + 1)
    centre = squared[r:r + cols]
    for y in range(rows):
        # the row's squared column distances, padded with "none within reach" on both sides
        for x in range(r):
            squared[x] = big
            squared[cols + r + x] = big
        row = column[y]
        for x in range(cols):
            centre[x] = row[x] * row[x]
        for x in range(cols):
            best[x] = centre[x]
        for dx in range(1, r + 1):
            dx2 = np.int32(dx * dx)
            left_row, right_row = squared[r - dx:r - dx + cols], squared[r + dx:r + dx + cols]
            for x in range(cols):
                left = left_row[x] + dx2
                right = right_row[x] + dx2
                m = left if left < right else right
                best[x] = m if m < best[x] else best[x]
        out_row = out[y]
        for x in range(cols):
            b = best[x]
            out_row[x] = np.sqrt(np.float32(b)) if b <= limit_sq else np.float32(reach_px)


class RegionMaps:
    """Builds :class:`DistanceMaps` of label images into buffers that it keeps between calls.

    Args:
        occlusion_aware: as :class:`DistanceMaps` (``PoseConfig.distance_maps == "occlusion_aware"``).

    One instance serves a stream: :meth:`build` for view ``index`` reuses that view's buffers
    while the region's shape is unchanged. The maps it returns are overwritten by the next
    :meth:`build` of the same view: use them (build the cost on them) before.
    """

    def __init__(self, *, occlusion_aware: bool):
        if occlusion_aware not in (True, False):
            raise ValueError(f"occlusion_aware must be True or False, got {occlusion_aware!r}")
        self.occlusion_aware = bool(occlusion_aware)
        self._tables = _lookup_tables(self.occlusion_aware)
        self._buffers: dict[int, dict] = {}
        self.n_allocations = 0  # buffer sets allocated, for the tests and the benchmark

    def build(self, index: int, view: View, labels: np.ndarray, reach_px: float | None = None) -> DistanceMaps:
        """The distance maps of ``labels`` (uint8 :class:`Feature` values of ``view``'s shape) for view ``index``.

        ``reach_px``: None, the exact distance everywhere; a number > 0, the exact distance where it is at
        most ``reach_px`` and ``reach_px`` where it is farther (a transform cut at the reach, several
        times cheaper than OpenCV's on a tracking region: docs/tracking.md). Every reader that caps
        the distances at ``reach_px`` or less (:meth:`~histostudy.pose.cost.PoseCost.capped`, which caps each
        bilinear corner) then reads the same numbers as on the exact maps."""
        if reach_px is not None and not (isinstance(reach_px, (int, float, np.integer, np.floating))
                                         and not isinstance(reach_px, bool) and np.isfinite(reach_px)
                                         and reach_px > 0):
            raise ValueError(f"reach_px must be None or a finite number > 0 (pixels), got {reach_px!r}")
        labels = np.asarray(labels)
        if labels.dtype != np.uint8 or labels.shape != view.shape:
            raise ValueError(f"labels must be a uint8 label image of view {view.name!r}'s shape {view.shape}, "
                             f"got {labels.dtype} {labels.shape}")
        labels = np.ascontiguousarray(labels)
        counts = np.bincount(labels.ravel(), minlength=256)
        if counts[len(Feature):].any():
            bad = sorted(int(v) for v in np.flatnonzero(counts[len(Feature):]) + len(Feature))
            raise ValueError(f"labels hold values {bad}, expected only Feature values 0-{len(Feature) - 1}")
        buffers = self._buffers.get(index)
        if buffers is None or buffers["shape"] != labels.shape:
            buffers = {"shape": labels.shape, "src": np.empty(labels.shape, np.uint8),
                       "maps": {f: np.empty(labels.shape, np.float32) for f in FEATURE_CLASSES}}
            self._buffers[index] = buffers
            self.n_allocations += 1
        rows, cols = labels.shape
        float32_exact = rows * rows + cols * cols < _FLOAT32_DIAGONAL_SQ
        maps = {}
        for feature in FEATURE_CLASSES:
            if not counts[int(feature)]:
                continue
            src = cv2.LUT(labels, self._tables[feature], dst=buffers["src"])
            out = buffers["maps"][feature]
            if reach_px is not None:
                _bounded_distance(src, np.float32(reach_px), out)
            elif float32_exact:
                cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE, dst=out)
                np.multiply(out, out, out=out)
                np.rint(out, out=out)
                np.sqrt(out, out=out)
            else:
                out[...] = euclidean_distance_map(src == 0)
            maps[feature] = out
        return DistanceMaps.from_maps(view, maps, occlusion_aware=self.occlusion_aware)
