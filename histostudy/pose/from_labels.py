"""Pose estimation from label images (§II-B.3-4): :func:`estimate_pose_from_labels`, the stages of
:func:`~histostudy.pose.estimate_pose` after the segmentation, each its own function. Poses are 4x4
``T_carm_transducer`` (mm); label images and pixel thresholds in their view's pixels.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from histostudy.core import check_items
from histostudy.imaging import View
from histostudy.transducer import TransducerModel

from .directions import DirectionStage, check_direction_pair
from .labels import clean_labels, view_distance_maps
from .options import PoseConfig, pose_generator
from .result import PoseResult, refused, result_of_refinement
from .retries import refine_with_retries
from .start import coarse_scorings, initialise
from .truncations import pose_costs
from .verdict import PoseJudge

__all__ = ["estimate_pose_from_labels"]


def estimate_pose_from_labels(labels_per_view: Sequence, views: Sequence[View] | View, model: TransducerModel, *,
                              orientation: DirectionStage | None = None,
                              rng: int | np.random.Generator | None = None, options: PoseConfig | None = None,
                              initial_pose=None, **option_overrides) -> PoseResult:
    """Estimate ``T_carm_transducer`` from each view's labels (docs/pose-estimation.md).

    Args:
        labels_per_view: one label image per view, ``(rows, cols)`` of that view, values
            :class:`~histostudy.transducer.Feature` (0 background .. 5 screws).
        views: the views the labels are in (>= 1; the paper: planes A and B).
        model: the digital model whose points enter eq. 3 (mm, transducer frame).
        orientation: the direction stage ``(view_index, labels, maps, rng) -> (2, 3)``, each view's
            two unit world focal-direction candidates (:mod:`.directions`; e.g.
            ``SourceDirections(source, frames)`` for an orientation source and the frames the labels
            came from). Needed unless ``initial_pose`` is given.
        rng: an int seed or a Generator for the point subsets, the orientation's draws and the
            silhouette seed; None: the fixed seed :data:`~.options.DEFAULT_SEED`
            (:func:`~.options.pose_generator`).
        options: a :class:`~.options.PoseConfig`, as for :func:`~histostudy.pose.estimate_pose`.
        **option_overrides: keyword overrides of its fields, as for :func:`~histostudy.pose.estimate_pose`.
        initial_pose: a 4x4 pose to start the refinement from (warm start): no orientation, no
            initialisation, no retries.

    Returns:
        :class:`~.result.PoseResult`: ``T_carm_transducer`` (4x4, mm), the cost, the seconds per
        stage, the verdict, and ``labels`` the labels after step 1.

    Raises:
        TypeError: ``views`` holds something other than views, ``model`` is not a
            ``TransducerModel`` or an option override is unknown.
        ValueError: neither ``orientation`` nor ``initial_pose`` is given, or a label image does
            not match its view.
        PoseEstimationError: a view shows no transducer feature, or the verdict refuses the pose
            and ``options.raise_on_failure`` is set.
    """
    t_start = time.perf_counter()
    views = check_items(views, "views", View, type_name="histostudy.imaging.View")
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel, got {type(model).__name__}")
    options = PoseConfig.resolve(options, option_overrides, caller="estimate_pose_from_labels",
                                  keywords="orientation, rng, options, initial_pose")
    rng = pose_generator(rng)
    if orientation is None and initial_pose is None:
        raise ValueError("orientation (a direction stage) is needed to estimate a pose without initial_pose")
    timings = {}
    t0 = time.perf_counter()
    labels = clean_labels(labels_per_view, views, largest_component=options.largest_component)
    timings["segmentation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    maps = view_distance_maps(views, labels, occlusion_aware=options.distance_maps == "occlusion_aware")
    timings["distance_maps"] = time.perf_counter() - t0
    costs = pose_costs(model.points, maps, options, rng)
    # Drawn for a warm start too: a caller's Generator (the tracker's, shared by its estimates)
    # then advances alike whichever start an estimate takes.
    scorings = coarse_scorings(costs, options, len(views), rng)
    initialisation = None
    if initial_pose is not None:
        T_init = np.asarray(initial_pose, dtype=np.float64)
        timings["orientation"] = timings["initialisation"] = 0.0
    else:
        assert orientation is not None
        t0 = time.perf_counter()
        candidates = [check_direction_pair(orientation(a, lab, m, rng), "the orientation stage")
                      for a, (lab, m) in enumerate(zip(labels, maps))]
        timings["orientation"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        initialisation = initialise(candidates, views, labels, model, costs, scorings, options, rng)
        T_init = initialisation.result.T_carm_transducer
        timings["initialisation"] = time.perf_counter() - t0
    out = refine_with_retries(costs, PoseJudge(costs, views, labels, model, options), T_init, initialisation,
                              options, timings)
    timings["total"] = time.perf_counter() - t_start
    result = result_of_refinement(
        out.refine, out.verdict, model.focal_point_mm, mode=options.mode, timings_s=timings, labels=labels,
        init=None if initialisation is None else initialisation.result,
        n_init_evaluations=0 if initialisation is None else initialisation.n_evaluations, retries=out.retries)
    if not out.verdict.ok and options.raise_on_failure:
        raise refused(result)
    return result
