"""The first stages of :func:`~histostudy.pose.estimate_pose` (§II-B.2-3): each view's label image
(:func:`segment_frames`, :func:`clean_labels`) and its distance maps (:func:`view_distance_maps`).
Label images are ``(rows, cols)`` arrays indexed ``[v, u]`` in the pixels of their view.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from histostudy.imaging import Frame, View
from histostudy.learning import keep_largest_component
from histostudy.transducer import check_label_image

from .distance_maps import DistanceMaps
from .result import PoseEstimationError

__all__ = ["clean_labels", "segment_frames", "view_distance_maps"]


def segment_frames(frames: Sequence[Frame], segmenter, rng: np.random.Generator) -> list:
    """Each frame's label image as the segmenter returns it (``segmenter.segment(frame, rng)``),
    in the frames' order; :func:`clean_labels` checks them."""
    return [segmenter.segment(f, rng) for f in frames]


def clean_labels(labels_per_view: Sequence, views: Sequence[View], *, largest_component: bool) -> list[np.ndarray]:
    """Each view's labels as a checked ``uint8`` label image of its view's shape, reduced to their
    largest connected component when ``largest_component`` (:class:`~.options.PoseConfig`: a
    segmentation's separate false positives would pull the search and fail the verdict).

    Raises ValueError naming the view whose labels have the wrong shape or values outside the
    feature classes."""
    labels_per_view = list(labels_per_view)
    if len(labels_per_view) != len(views):
        raise ValueError(f"labels_per_view must hold one label image per view ({len(views)}), "
                         f"got {len(labels_per_view)}")
    labels = [check_label_image(lab, v.shape, f"the segmentation of view {v.name or a}")
              for a, (lab, v) in enumerate(zip(labels_per_view, views))]
    if largest_component:
        labels = [keep_largest_component(lab) for lab in labels]
    return labels


def view_distance_maps(views: Sequence[View], labels: Sequence[np.ndarray], *,
                       occlusion_aware: bool) -> list[DistanceMaps]:
    """Eq. 3's distance maps of each view's labels (pixels of that view); ``occlusion_aware``: a
    pixel of a higher-priority class counts for the classes it hides (:class:`DistanceMaps`).

    Raises :class:`~.result.PoseEstimationError` when a view shows no transducer feature."""
    maps = [DistanceMaps(v, lab, occlusion_aware=occlusion_aware) for v, lab in zip(views, labels)]
    for v, m in zip(views, maps):
        if not m.present:
            raise PoseEstimationError(f"view {v.name!r}: no transducer feature was segmented; the "
                                      f"transducer is not in this view or the segmentation failed")
    return maps
