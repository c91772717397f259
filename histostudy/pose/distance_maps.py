"""Distance maps of §II-B.3: for one view, the exact Euclidean distance (pixels) from every pixel to
the nearest segmented pixel of each feature class, the ``min_j`` of eq. 3 (:class:`DistanceMaps`).
Maps are ``(rows, cols)`` float32 on the view's detector, pixel centres at integers.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import cv2
import numpy as np

from histostudy.imaging import View
from histostudy.transducer import FEATURE_CLASSES, LABEL_PRIORITY, Feature

__all__ = ["DistanceMaps", "euclidean_distance_map"]

#: Below this squared distance (px²) the distance maps are rounded to exact values (see
#: :func:`euclidean_distance_map`).
_EXACT_SQ_LIMIT = float(2 ** 21)


def feature_class(key, name: str) -> Feature:
    """``key`` as one of the five point classes, or a ValueError naming the argument ``name``
    (shared with :class:`~.cost.PoseCost`, whose points and weights are keyed the same way)."""
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

    Raises:
        TypeError: ``view`` is not a ``View``.
        ValueError: ``view`` is smaller than 2x2 pixels, ``segmentation`` is neither a label image
            of Feature values nor a dict of boolean masks of the view's shape, or
            ``occlusion_aware`` is not True or False.
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
                feature = feature_class(key, "segmentation")
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

    @classmethod
    def from_maps(cls, view: View, maps: Mapping, *, occlusion_aware: bool) -> DistanceMaps:
        """Distance maps made elsewhere, wrapped for :class:`~.cost.PoseCost` without recomputing them
        (e.g. :class:`~histostudy.pose.tracking._maps.RegionMaps`, which writes a tracking region's maps into reused
        buffers). ``maps``: ``{Feature: (rows, cols) float32}`` distances in pixels of ``view``, one
        per class present (as :attr:`maps`); ``occlusion_aware`` says how they were made. The
        arrays are kept, not copied."""
        out = cls.__new__(cls)
        out.view = _check_view(view)
        if occlusion_aware not in (True, False):
            raise ValueError(f"occlusion_aware must be True or False, got {occlusion_aware!r}")
        out.occlusion_aware = bool(occlusion_aware)
        if not isinstance(maps, Mapping):
            raise TypeError(f"maps must be a dict {{Feature: (rows, cols) float32}}, got {type(maps).__name__}")
        checked = {}
        for key, value in maps.items():
            feature = feature_class(key, "maps")
            if not isinstance(value, np.ndarray) or value.dtype != np.float32 or value.shape != view.shape:
                raise ValueError(f"maps[{feature.name}] must be a float32 array of view {view.name!r}'s shape "
                                 f"{view.shape}, got {getattr(value, 'dtype', type(value).__name__)} "
                                 f"{getattr(value, 'shape', '')}")
            checked[feature] = value
        out.maps = {f: checked[f] for f in FEATURE_CLASSES if f in checked}
        out.present = tuple(out.maps)
        out.absent = tuple(f for f in FEATURE_CLASSES if f not in out.maps)
        return out

    @property
    def shape(self) -> tuple[int, int]:
        return self.view.shape

    def truncated(self, max_distance_px: float) -> DistanceMaps:
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

