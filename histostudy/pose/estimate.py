"""Transducer pose estimation from fluoroscopy (paper §II-B.3, §II-B.4): :func:`estimate_pose`.

Stages, each timed: segmentation of every frame (a :class:`~histostudy.learning.segment.Segmenter`),
exact distance maps per view and class (:class:`~.distance_maps.DistanceMaps`), the orientation from
each view's azimuth/elevation (an :class:`~histostudy.learning.orientation.OrientationSource`) with the
mirror ambiguity resolved across views, the translation grid search and the axial search
(:mod:`.init`, :mod:`.silhouette`), then the refinement of eq. 3 (:mod:`.refine`): Nelder-Mead in
the paper's mode, Levenberg-Marquardt in the fast mode. A pose that the data do not support — no
features in a view, a final cost too high, a model pushed out of the views or off the search
region — raises :class:`~.result.PoseEstimationError` (or comes back with a failed verdict,
:mod:`.verdict`) instead of a confident garbage pose. How it runs is a :class:`~.options.PoseOptions`.

Any number of views >= 1 is accepted: a biplane pair as in the paper, or a single-plane C-arm
moved to several angles (§II-B). With one view the mirror ambiguity of eq. 4 is resolved by
running the search for both candidates and keeping the lower cost. Poses are 4x4
``T_carm_transducer`` (mm, C-arm/CBCT frame).
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from histostudy.imaging import Frame
from histostudy.learning import (OrientationSource, Segmenter, direction_candidates, keep_largest_component,
                                 select_direction)
from histostudy.transducer import Feature, TransducerModel, check_label_image
from .cost import PoseCost
from .distance_maps import DistanceMaps
from .init import MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG, ROBUST_AXIAL_SEEDS_DEG, initialise_pose
from .learned_stages import default_stages
from .options import PoseOptions
from .refine import refine_levenberg_marquardt, refine_nelder_mead
from .result import PoseEstimationError, PoseResult
from .silhouette import silhouette_candidates
from .verdict import check_unexplained, check_view_agreement, judge_fit

__all__ = ["estimate_pose"]

#: Model points (elements and outer boundary) whose projected occupancy the robust
#: initialisation's silhouette seed compares with the segmented one.
SILHOUETTE_POINTS = 4000


def estimate_pose(frames: Sequence[Frame], model: TransducerModel, *, segmenter: Segmenter | None = None,
                  orientation: OrientationSource | None = None, rng: np.random.Generator | None = None,
                  initial_pose=None, options: PoseOptions | None = None, **option_overrides) -> PoseResult:
    """Estimate ``T_carm_transducer`` from one or more frames (§II-B.3-4).

    Args:
        frames: the fluoroscopic frames, each with its view (>= 1; the paper: planes A and B).
        model: the digital model whose points enter eq. 3 (the paper: the 0.47 mm model).
        segmenter: frame -> label image; default: the shipped U-Net when its weights are present
            and pass their check, else :class:`OracleSegmenter` (the frames' reference labels, a
            synthetic-study stand-in that cannot segment a real frame) — see :func:`default_stages`.
        orientation: frame -> (azimuth, elevation); default: the shipped stage of
            :func:`histostudy.pose.conic_orientation.default_orientation` (the inner-boundary conic
            initialiser, the VGG19 regressor where a view shows no ellipse), else
            :class:`OracleOrientation` (the true angles with the paper's errors). A source with a
            ``direction_candidates_from_labels(frame, labels, rng, maps=)`` method (the geometric
            :class:`~histostudy.pose.conic_orientation.ConicOrientation`) is given the segmentation
            made here and returns each view's two candidate directions itself.
        rng: Generator for the segmenter's and orientation's draws and the point subsets; default
            ``numpy.random.default_rng(0)``.
        initial_pose: a 4x4 pose to start the refinement from (tracking warm start); skips the
            initialisation.
        options: how to run: mode, initialisation, distance maps, truncations, verdict
            thresholds (:class:`~.options.PoseOptions`; default ``PoseOptions()``).
        **option_overrides: any field of :class:`~.options.PoseOptions` as a keyword
            (``mode="fast"``, ``refine_truncation_px=None``, ...); each overrides that field of
            ``options``. An unknown keyword raises TypeError.

    Returns:
        :class:`~.result.PoseResult`. Raises :class:`~.result.PoseEstimationError` when a view
        shows no feature, or on a failed verdict when ``options.raise_on_failure``.
    """
    t_start = time.perf_counter()
    frames = _check_frames(frames)
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel, got {type(model).__name__}")
    options = _resolve_options(options, option_overrides)
    rng = np.random.default_rng(0) if rng is None else rng
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    segmenter = default_stages()[0] if segmenter is None else segmenter
    orientation = default_stages()[1] if orientation is None else orientation
    timings = {}

    t0 = time.perf_counter()
    labels = [check_label_image(segmenter.segment(f, rng), f.shape, f"the segmentation of view {f.view.name or a}")
              for a, f in enumerate(frames)]
    if options.largest_component:
        labels = [keep_largest_component(lab) for lab in labels]
    timings["segmentation"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    occlusion_aware = options.distance_maps == "occlusion_aware"
    maps = [DistanceMaps(f.view, lab, occlusion_aware=occlusion_aware) for f, lab in zip(frames, labels)]
    timings["distance_maps"] = time.perf_counter() - t0
    for f, m in zip(frames, maps):
        if not m.present:
            raise PoseEstimationError(f"view {f.view.name!r}: no transducer feature was segmented; the "
                                      f"transducer is not in this view or the segmentation failed")
    # One flattened copy of the maps; every capped or subset cost below shares it.
    cost = PoseCost(model.points, maps, class_weights=options.class_weights,
                    outside_distance_px=options.outside_distance_px)
    refine_cost = cost.capped(options.refine_truncation_px)
    coarse = cost.subset(options.init_points_per_class, rng)
    verdict_cost = coarse.capped(options.verdict_truncation_px)
    if options.init == "robust":
        tau = float(options.search_truncation_px)
        search = coarse.capped(tau, outside_distance_px=tau)
        # The local refinements' robust cost: the same truncated distances, but eq. 3's own
        # constant for points off the detector. With the truncation as the off-detector cost, a
        # pose that pulls more of the model onto the detector wins over a better-aligned one
        # (measured: a 1-2 mm pull on frames where much of the transducer is outside the view).
        polish_cost = search.with_outside_distance(options.outside_distance_px)
        tau_coarse = float(options.coarse_truncation_px)
        # Off the detector a point is unknown. Costing it the full truncation, a pose that pulls
        # more of the model into a view where the transducer is mostly outside can beat the true
        # region; at half the truncation a pose with most of the model off the detectors can
        # beat a near miss of the coarse grid (both measured). Each scoring proposes its chains;
        # the narrower search cost decides after the medium and fine grids.
        # A 3 cm grid needs no more than a few hundred points per class to rank its nodes.
        coarse_scorings = []
        coarse_subset = coarse.subset(max(1, options.init_points_per_class // 5), rng)
        coarse_full = coarse_subset.capped(tau_coarse, outside_distance_px=tau_coarse)
        for c in (coarse_full, coarse_full.with_outside_distance(0.5 * tau_coarse)):
            coarse_scorings.append(([c.select_views(i) for i in range(len(frames))], c))
    else:
        search = polish_cost = coarse

    init_result = None
    n_init_eval = 0
    deferred_directions = []
    if initial_pose is not None:
        T_init = np.asarray(initial_pose, dtype=np.float64)
        timings["orientation"] = timings["initialisation"] = 0.0
    else:
        t0 = time.perf_counter()
        candidates = [_view_direction_candidates(orientation, f, lab, m, rng) for f, lab, m in zip(frames, labels, maps)]
        timings["orientation"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        view_costs = [search.select_views(i) for i in range(len(frames))]
        views = [f.view for f in frames]
        if len(frames) == 1:
            tries = [candidates[0][0], candidates[0][1]]
        else:
            direction, _, spread = select_direction(candidates)
            tries = [direction]
            if options.init == "robust":
                per_view = [c for view_candidates in candidates for c in view_candidates]
                if np.rad2deg(spread) > options.direction_spread_limit_deg:
                    tries += per_view
                else:
                    deferred_directions = per_view
        if options.init == "robust":
            def polish(T):
                # Truncated distances: points on missed or hidden features do not pull. Scored by
                # the search cost, so that hypotheses compare as the grids and axial search did.
                r = refine_levenberg_marquardt(polish_cost, T, max_iter=30)
                return r.T, float(search(r.T))
            init_options = dict(axial_seeds_deg=ROBUST_AXIAL_SEEDS_DEG, fine_after_axial=True, n_hypotheses=3,
                           polish=polish, medium=MEDIUM_GRID, coarse_scorings=coarse_scorings,
                           coarse_candidates=3)
            if len(frames) > 1:
                silhouettes = [lab > 0 for lab in labels]
                body = np.vstack([model.points[k] for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY)
                                  if k in model.points])
                body = body[rng.choice(len(body), size=min(len(body), SILHOUETTE_POINTS), replace=False)]
                centre_local = body.mean(axis=0)
                init_options["seeded"] = lambda d: [(a, t) for a, t, _ in silhouette_candidates(
                    d, views, silhouettes, body, centre_local_mm=centre_local)]
        else:
            init_options = dict(axial_seeds_deg=PAPER_AXIAL_SEEDS_DEG, fine_after_axial=False, n_hypotheses=1)

        def start(directions):
            results = [initialise_pose(d, views, view_costs, search, centre_mm=options.search_centre_mm,
                                       **init_options) for d in directions]
            return min(results, key=lambda r: r.cost), sum(r.n_evaluations for r in results)

        init_result, n_init_eval = start(tries)
        init_result.stages["direction_starts"] = len(tries)
        if len(frames) > 1:
            init_result.stages["direction_spread_deg"] = float(np.rad2deg(spread))
        T_init = init_result.T_carm_transducer
        timings["initialisation"] = time.perf_counter() - t0

    def refine(T0, method=options.mode):
        if method == "paper":
            return refine_nelder_mead(refine_cost, T0)
        # Coarse-to-fine: the truncated point subset first (robust to missed and spurious
        # features, ~20x cheaper per pass), then eq. 3 on every model point (capped at
        # refine_truncation_px unless None). The capped cost of a learned segmentation has long,
        # nearly flat valleys: stopped at a 1e-3 relative decrease, the focal point sat 0.63 mm
        # (median) from the truth where the same refinement run on to 1e-6 reached 0.46 mm
        # (92 random poses, shipped U-Net; 0.2-0.5 s more per estimate).
        return refine_levenberg_marquardt(refine_cost, T0, coarse=polish_cost, ftol=1e-6, xtol_mm=1e-4, xtol_rad=1e-6,
                                          max_iter=50)

    check_agreement = len(frames) > 1 and options.max_view_disagreement_mm is not None
    if check_agreement:
        consistency_cost = coarse.capped(1.0 if options.refine_truncation_px is None else options.refine_truncation_px)
    if options.max_unexplained_fraction is not None:
        # Stacked once here: every verdict below projects all of the model's points.
        model_points_mm = np.vstack([p for p in model.points.values() if len(p)])

    def judge(T):
        # The verdict's thresholds are coarse (pixels, percent): the point subset judges as well
        # as the whole model at a fraction of the time.
        verdict = judge_fit(verdict_cost, frames, T, options.search_centre_mm, options.max_rms_px,
                            options.min_inside_fraction, options.max_body_rms_px if occlusion_aware else None)
        if options.max_unexplained_fraction is not None:
            check_unexplained(verdict, frames, labels, model, T, options.max_unexplained_fraction,
                              10.0 if options.verdict_truncation_px is None else options.verdict_truncation_px,
                              points_mm=model_points_mm)
        if verdict.ok and check_agreement:
            check_view_agreement(verdict, consistency_cost, frames, T, model.focal_point_mm,
                                 options.max_view_disagreement_mm)
        return verdict

    t0 = time.perf_counter()
    refined = refine(T_init)
    timings["refinement"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    verdict = judge(refined.T)
    timings["verdict"] = time.perf_counter() - t0
    retries = 0
    if not verdict.ok and init_result is not None and options.retry_hypotheses:
        # The best-scoring initial hypothesis led to an implausible pose: refine the others
        # (other axial minima of §II-B.4's search) and keep the lowest final cost among the
        # plausible ones.
        t0 = time.perf_counter()
        for T_hyp, _ in sorted(init_result.hypotheses, key=lambda h: h[1])[1:]:
            retries += 1
            candidate = refine(T_hyp)
            candidate_verdict = judge(candidate.T)
            if candidate_verdict.ok and (not verdict.ok or candidate.cost < refined.cost):
                refined, verdict = candidate, candidate_verdict
        if not verdict.ok and deferred_directions:
            # The views agreed on a direction, but it led nowhere plausible: both estimates may be
            # off alike. Start again from each view's own two direction candidates.
            retries += 1
            restart, n_eval = start(deferred_directions)
            n_init_eval += n_eval
            init_result.stages["direction_starts"] += len(deferred_directions)
            candidate = refine(restart.T_carm_transducer)
            candidate_verdict = judge(candidate.T)
            if candidate_verdict.ok:
                refined, verdict = candidate, candidate_verdict
        if not verdict.ok and options.mode == "fast":
            # Last resort: the simplex explores a 2 deg / 2 mm neighbourhood where a
            # gradient step cannot leave a spurious basin of the segmentation errors.
            retries += 1
            candidate = refine(init_result.T_carm_transducer, "paper")
            candidate_verdict = judge(candidate.T)
            if candidate_verdict.ok:
                refined, verdict = candidate, candidate_verdict
        timings["retries"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start

    focal = refined.T[:3, :3] @ np.asarray(model.focal_point_mm, dtype=np.float64) + refined.T[:3, 3]
    result = PoseResult(T_carm_transducer=refined.T, focal_point_mm=focal, cost=refined.cost,
                        iterations=refined.iterations, evaluations=refined.evaluations + n_init_eval,
                        timings_s=timings, verdict=verdict, mode=options.mode, init=init_result, refine=refined,
                        labels=labels, retries=retries)
    if not verdict.ok and options.raise_on_failure:
        raise PoseEstimationError("implausible pose: " + "; ".join(verdict.reasons), verdict, result)
    return result


def _view_direction_candidates(orientation, frame: Frame, labels: np.ndarray, maps: DistanceMaps, rng) -> np.ndarray:
    """``(2, 3)`` world focal-direction candidates of one view: the source's own pair when it reads
    them from the labels and distance maps already made (``direction_candidates_from_labels(frame,
    labels, rng, maps=)``, e.g. :class:`~histostudy.pose.conic_orientation.ConicOrientation`: no second
    segmentation), else eq. 4's mirror pair of its ``(azimuth, elevation)``."""
    from_labels = getattr(orientation, "direction_candidates_from_labels", None)
    if from_labels is not None:
        pair = np.asarray(from_labels(frame, labels, rng, maps=maps), dtype=np.float64)
        if pair.shape != (2, 3) or not np.all(np.isfinite(pair)):
            raise ValueError(f"{type(orientation).__name__}.direction_candidates_from_labels returned shape "
                             f"{pair.shape}; expected two finite world directions (2, 3)")
        return pair / np.linalg.norm(pair, axis=1, keepdims=True)
    return direction_candidates(*orientation.estimate(frame, rng), frame.view)


def _check_frames(frames) -> list[Frame]:
    if isinstance(frames, Frame):
        frames = [frames]
    frames = list(frames)
    if not frames:
        raise ValueError("frames must hold at least one Frame, got none")
    for i, f in enumerate(frames):
        if not isinstance(f, Frame):
            raise TypeError(f"frames[{i}] must be a histostudy.imaging.frame.Frame, got {type(f).__name__}")
    return frames


def _resolve_options(options, overrides: dict) -> PoseOptions:
    """``options`` (default ``PoseOptions()``) with the keyword ``overrides`` of its fields applied."""
    return PoseOptions.resolve(options, overrides, caller="estimate_pose",
                               keywords="segmenter, orientation, rng, initial_pose, options")
