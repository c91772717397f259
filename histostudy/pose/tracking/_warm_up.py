"""Warming a tracker up before its first live pair (:meth:`Tracker.warm_up
<histostudy.pose.tracking.Tracker.warm_up>`): one from-scratch estimate and one warm update on a
synthetic pair, then the tracker put back as it was (docs/tracking.md, "Module notes").
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from histostudy.imaging import Frame, View, render_frame
from histostudy.transducer import TransducerModel, pose_facing

from ..result import PoseEstimationError

__all__ = ["views_isocentre_mm", "warm_up_pair"]

#: The synthetic pair's transducer axis (world, LPS): tilted from the anterior-posterior default
#: so that neither view sees the aperture edge-on, as in the paper's set-up (§II-C).
_WARM_UP_DIRECTION = (0.25, 1.0, 0.15)
_WARM_UP_AXIAL_RAD = 0.6


def views_isocentre_mm(views: Sequence[View]) -> np.ndarray:
    """The point nearest (least squares) to the views' central rays, source to detector centre
    (world mm): where a C-arm's views look together."""
    origins, directions = [], []
    for view in views:
        rows, cols = view.shape
        origins.append(np.asarray(view.source_mm, dtype=np.float64))
        directions.append(np.asarray(view.ray_directions(np.array([[(cols - 1) / 2.0, (rows - 1) / 2.0]])),
                                     dtype=np.float64).reshape(3))
    projectors = [np.eye(3) - np.outer(d, d) for d in directions]
    return np.linalg.solve(sum(projectors), sum(P @ o for P, o in zip(projectors, origins)))


def warm_up_pair(model: TransducerModel, views: Sequence[View], rng: np.random.Generator) -> list[Frame]:
    """A noisy synthetic frame per view of ``model`` with its focal point at the views' isocentre
    (:func:`views_isocentre_mm`), axis tilted from anterior-posterior; no background. Draws the
    renderer's splat jitter and Poisson noise from ``rng``."""
    if len(views) < 2:
        raise ValueError(f"views must hold two or more views to warm a tracker up, got {len(views)}")
    T = pose_facing(_WARM_UP_DIRECTION, views_isocentre_mm(views), _WARM_UP_AXIAL_RAD)
    return [render_frame(model, T, view, rng=rng, device="cpu") for view in views]


def warm_up(tracker, frames=None, *, seed: int = 0) -> dict:
    """Run ``tracker`` over ``frames`` (default :func:`warm_up_pair` of its model and views, drawn
    from ``seed``) twice — from scratch, then warm — and put it back as it was (docs/tracking.md).
    Returns ``{"seconds": wall seconds, "kinds": [each update's kind], "accepted": [each verdict]}``."""
    if frames is None:
        frames = warm_up_pair(tracker.model, tracker.views, np.random.default_rng(seed))
    saved_rng = tracker.rng.bit_generator.state
    saved = {name: getattr(tracker, name) for name in ("_last_pose", "last_result", "last_kind", "_refused_pose",
                                                       "stage_seconds", "update_seconds", *tracker.COUNTERS)}
    saved_regions = None if tracker._region is None else list(tracker._region.last_regions)
    t_start = time.perf_counter()
    kinds, accepted = [], []
    try:
        tracker.reset()
        for _ in range(2):
            try:
                accepted.append(bool(tracker.update(frames).verdict.ok))
            except PoseEstimationError:  # raise_on_failure: a refused warm-up pose still ran every stage
                accepted.append(False)
            kinds.append(tracker.last_kind)
    finally:
        tracker.rng.bit_generator.state = saved_rng
        for name, value in saved.items():
            setattr(tracker, name, value)
        if saved_regions is not None:
            tracker._region.last_regions = saved_regions
    return {"seconds": time.perf_counter() - t_start, "kinds": kinds, "accepted": accepted}
