"""Distance maps of a tracking region (§II-B.3), written into buffers reused frame after frame:
:class:`RegionMaps`.

The same maps as :class:`~.distance_maps.DistanceMaps` (the exact Euclidean distance in pixels
from every pixel of a label image to the nearest pixel of each class, or of a class of higher
overlap priority with ``occlusion_aware``; OpenCV's Felzenszwalb-Huttenlocher transform), built
for a stream of label images of a region (``histostudy.pose.tracking_roi``) rather than once per
frame:

- one pass per class over the labels, through a look-up table that gives OpenCV's input (0 on the
  class, and on the classes that hide it with ``occlusion_aware``; 1 elsewhere) directly;
- the transform and the rounding of ``d²`` to its integer (see
  :func:`~.distance_maps.euclidean_distance_map`) done in float32 in place: exact wherever
  ``d² < 2**20`` (the float32 square of OpenCV's value is then within 0.25 of the integer), which
  holds for every pixel of a region whose diagonal is under 1024 px. Larger regions go through
  :func:`~.distance_maps.euclidean_distance_map`'s float64 rounding. Either way the values equal
  :class:`DistanceMaps`' (tests/pose/test_tracking_maps.py);
- buffers kept per view and class and reused while the region's shape stays the same, so a
  warm update allocates no map (a :class:`~.cost.PoseCost` built on them copies them once into its
  flat buffer).

Frame: the region view's detector, pixel centres at integers; maps ``(rows, cols)`` float32, pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from histostudy.imaging import View
from histostudy.transducer import FEATURE_CLASSES, LABEL_PRIORITY, Feature
from .distance_maps import DistanceMaps, euclidean_distance_map

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


class RegionMaps:
    """Builds :class:`DistanceMaps` of label images into buffers that it keeps between calls.

    Args:
        occlusion_aware: as :class:`DistanceMaps` (``PoseOptions.distance_maps == "occlusion_aware"``).

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

    def build(self, index: int, view: View, labels: np.ndarray) -> DistanceMaps:
        """The distance maps of ``labels`` (uint8 :class:`Feature` values of ``view``'s shape) for view ``index``."""
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
            if float32_exact:
                cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE, dst=out)
                np.multiply(out, out, out=out)
                np.rint(out, out=out)
                np.sqrt(out, out=out)
            else:
                out[...] = euclidean_distance_map(src == 0)
            maps[feature] = out
        return DistanceMaps.from_maps(view, maps, occlusion_aware=self.occlusion_aware)
