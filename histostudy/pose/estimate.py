"""Transducer pose estimation from fluoroscopy (paper §II-B.3, §II-B.4): :func:`estimate_pose`.

Stages, each timed: segmentation of every frame (a :class:`~histostudy.learning.segment.Segmenter`),
exact distance maps per view and class (:class:`~.cost.DistanceMaps`), the orientation from
each view's azimuth/elevation (an :class:`~histostudy.learning.orientation.OrientationSource`) with the
mirror ambiguity resolved across views, the translation grid search and the axial search
(:mod:`.init`), then the refinement of eq. 3 (:mod:`.refine`): Nelder-Mead in the paper's mode,
Levenberg-Marquardt in the fast mode. A pose that the data do not support — no features in a
view, a final cost too high, a model pushed out of the views or off the search region — raises
:class:`PoseEstimationError` (or comes back with a failed verdict) instead of a confident
garbage pose.

Any number of views >= 1 is accepted: a biplane pair as in the paper, or a single-plane C-arm
moved to several angles (§II-B). With one view the mirror ambiguity of eq. 4 is resolved by
running the search for both candidates and keeping the lower cost.
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from histostudy.imaging import Frame
from histostudy.learning import (OracleOrientation, OracleSegmenter, OrientationSource, Segmenter, default_segmenter,
                                 direction_candidates, keep_largest_component, select_direction)
from histostudy.transducer import Feature, TransducerModel
from .conic_orientation import default_orientation
from .cost import DistanceMaps, PoseCost
from .init import (InitResult, MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG, ROBUST_AXIAL_SEEDS_DEG, initialise_pose,
                   silhouette_candidates)
from .refine import RefineResult, refine_levenberg_marquardt, refine_nelder_mead
from .verdict import (PoseVerdict, check_unexplained, check_view_agreement, judge_fit, unexplained_fraction,
                      view_disagreement_mm)

__all__ = ["INIT_METHODS", "LEARNED_STAGE_REQUIREMENTS", "learned_stage_shortfalls", "MAP_KINDS", "MODES", "PoseEstimationError", "PoseResult", "PoseVerdict", "default_stages",
           "estimate_pose", "unexplained_fraction", "view_disagreement_mm"]

MODES = ("paper", "fast")
INIT_METHODS = ("robust", "paper")
MAP_KINDS = ("occlusion_aware", "per_class")
#: Model points (elements and outer boundary) whose projected occupancy the robust
#: initialisation's silhouette seed compares with the segmented one.
SILHOUETTE_POINTS = 4000


class PoseEstimationError(RuntimeError):
    """The frames do not support a pose: no features, or an implausible result (see ``verdict``)."""

    def __init__(self, message: str, verdict: "PoseVerdict | None" = None, result: "PoseResult | None" = None):
        super().__init__(message)
        self.verdict = verdict
        self.result = result


@dataclass
class PoseResult:
    """What :func:`estimate_pose` found.

    Attributes:
        T_carm_transducer: 4x4 pose, transducer -> C-arm (CBCT) frame.
        focal_point_mm: the model's geometric focal point in CBCT mm (eq. 5, ``f_c = hTc f_h``).
        cost: eq. 3 at the pose (px², summed over views).
        iterations, evaluations: of the refinement (evaluations also count the initialisation's).
        timings_s: seconds per stage: segmentation, distance_maps, orientation, initialisation,
            refinement, verdict, total.
        verdict: the plausibility checks.
        mode: ``"paper"`` or ``"fast"``.
        init: the initialisation's record (None for a warm start).
        refine: the refinement's record.
        labels: the segmentation of each frame the cost was built on.
        retries: initial hypotheses refined after the first failed the verdict.
    """

    T_carm_transducer: np.ndarray
    focal_point_mm: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    timings_s: dict
    verdict: PoseVerdict
    mode: str
    init: InitResult | None
    refine: RefineResult
    labels: list = field(repr=False, default_factory=list)
    retries: int = 0


def estimate_pose(frames: Sequence[Frame], model: TransducerModel, *, segmenter: Segmenter | None = None,
                  orientation: OrientationSource | None = None, rng: np.random.Generator | None = None,
                  mode: str = "paper", init: str = "robust", distance_maps: str = "occlusion_aware",
                  initial_pose=None, class_weights: dict | None = None, outside_distance_px: float = 0.1,
                  search_truncation_px: float = 30.0, coarse_truncation_px: float = 150.0, init_points_per_class: int = 1500,
                  search_centre_mm=(0.0, 0.0, 0.0), max_rms_px: float = 6.0, min_inside_fraction: float = 0.02,
                  raise_on_failure: bool = True, retry_hypotheses: bool = True,
                  direction_spread_limit_deg: float = 15.0, refine_truncation_px: float | None = 1.0,
                  verdict_truncation_px: float | None = 10.0,
                  max_view_disagreement_mm: float | None = 1.5,
                  max_body_rms_px: float | None = 1.0, max_unexplained_fraction: float | None = 0.1,
                  largest_component: bool = True) -> PoseResult:
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
        mode: ``"paper"`` (Nelder-Mead, 1000 iterations, tolerances 0.01) or ``"fast"``
            (Levenberg-Marquardt with analytic Jacobian, coarse-to-fine).
        init: ``"paper"`` runs §II-B.4 as written: the translation grids at one axial angle, scored
            by eq. 3 with the paper's 0.1 px constant, then the axial search. ``"robust"`` (default)
            scores the grid and axial searches with distances truncated at
            ``search_truncation_px`` (points off the detector count as truncated too), seeds the
            coarse grids at four axial angles (scored with distances truncated at
            ``coarse_truncation_px``, about a coarse grid step, for a basin as wide as the grid,
            off-detector points at that and at half of it, three chains of each carried on),
            adds a 1 cm medium grid before the fine one, repeats the fine grids after the axial search and
            carries the three best axial minima through a short Levenberg-Marquardt polish. With two
            or more views, a silhouette seed (:func:`~.init.silhouette_candidates`: the visible
            part's occupancy centroids matched by Gauss-Newton, the axial angle chosen by the
            silhouettes' overlap) proposes two more chains, and the best of them is carried
            through the axial search beside the best coarse chain: where most of the transducer is
            off the detectors, the coarse grid's scores are nearly flat (notebook 04's robustness
            sweep: 93 % -> 98-99 % success at 0.25 mm renders). With
            the paper's constant a pose with the whole model off the detector costs 0.01 px² per
            class, less than any real alignment: the grid search then returns it (measured in
            notebook 04's robustness sweep).
        distance_maps: ``"per_class"`` builds eq. 3's maps as written (distance to the nearest
            pixel of the same class); ``"occlusion_aware"`` (default, beyond the paper) lets a
            pixel of a higher-priority class count for the classes it hides (see
            :class:`~.cost.DistanceMaps`): with priority-resolved labels, per-class maps bias the
            optimum by up to about 1 mm on noise-free frames, occlusion-aware maps by a few
            hundredths (tests/test_pose_estimate.py; notebook 04 compares both).
        initial_pose: a 4x4 pose to start the refinement from (tracking warm start); skips the
            initialisation.
        class_weights: eq. 3's ``lambda_k`` (default 1 each).
        outside_distance_px: eq. 3's constant distance for points off the map (paper 0.1 px).
        init_points_per_class: points per class of the cheaper cost the grid and axial searches use.
        search_centre_mm: centre of the first translation grid (paper: the isocentre).
        max_rms_px, min_inside_fraction: verdict thresholds (see :class:`PoseVerdict`). The RMS
            threshold allows for a learned segmentation's label noise: with the shipped U-Net,
            correct poses (< 2 mm) reach 4-6 px (30 random poses, seed 4242); it no longer tells
            a wrong pose alone, ``max_view_disagreement_mm`` does (docs/learned-stages.md).
        max_body_rms_px: beyond the paper; the largest RMS distance (px, per view) of the
            element body's model points (:attr:`Feature.TRANSDUCER`, the class a segmentation
            finds best: the shipped U-Net's IoU 0.94). At a right pose they lie on it even when
            the thin classes are half missed; a pose turned or shifted by millimetres moves them
            off. With the shipped U-Net, estimates within 2 mm of 100 random poses (seed 5151)
            had a median of 0.07 px and a 95th percentile of 0.19 px; five of the seven off by
            more had 1.0-5.4 px. Judged with the occlusion-aware maps only: with per-class maps a
            body point under a thin feature is off its class by the feature's width. None skips
            the check.
        largest_component: beyond the paper; keep only the largest connected component of each
            view's segmented foreground (:func:`~histostudy.learning.segment.keep_largest_component`): the
            transducer projects as one body, so other components are a segmentation's false
            positives, which would otherwise pull the search and fail the unexplained-segmentation
            check. ``PoseResult.labels`` are the labels after this step.
        max_unexplained_fraction: beyond the paper; the largest fraction of a view's segmented
            pixels that may lie farther than ``verdict_truncation_px`` from every projected model
            point (:attr:`PoseVerdict.unexplained_fraction`). Eq. 3 and the RMS look from the model
            to the labels only: a pose that pushes most of the model off the detectors fits what
            stays on it, with the rest of the segmented transducer left unexplained (measured: a
            pose 117 mm off, RMS 4.7 px, 41 % of view A's segmentation unexplained; poses within
            2 mm, at most 2 %). None skips the check.
        max_view_disagreement_mm: beyond the paper; with two or more views, the cross-view check of
            a pose that passed the others. From the pose, each view's cost alone (distances capped
            at ``refine_truncation_px``, 1 px if None) is minimised by Levenberg-Marquardt; the
            focal point's move across that view's ray through it (the depth, which one view does
            not fix, left out) is the view's disagreement. Where both views' features fit the
            pose, neither pulls it away; a pose that trades one view's misread features against
            the other's sits between two single-view optima and fails. Chosen on 30 random poses
            (seed 4242, shipped U-Net): estimates within 2 mm moved at most 1.25 mm, four of the
            five wrong ones 1.9-3.1 mm; validated on fresh seeds in docs/learned-stages.md. None
            skips the check.
        raise_on_failure: raise :class:`PoseEstimationError` on a failed verdict (else return it).
        retry_hypotheses: when the refinement from the best initial hypothesis fails the verdict,
            refine the initialisation's other hypotheses too (``init="robust"`` keeps three) and
            keep the plausible one of lowest cost; in the fast mode, if none is plausible, the
            best hypothesis is refined by Nelder-Mead as a last resort. ``timings_s["retries"]``
            then holds their time.
        refine_truncation_px: beyond the paper. The refinement (both modes) minimises eq. 3 with
            each distance capped at this many pixels; None minimises eq. 3 as written. A U-Net
            misses whole stretches of a thin class (a gap line, a part of the rim): eq. 3's
            squared distances let the model points there, tens of pixels from any pixel of their
            class, pull the pose by millimetres. Capped, they cost a constant and pull nothing,
            while every point within the cap counts as in eq. 3; the refinement starts from the
            initialisation's pose, already fitted with 30 px caps, so a narrow cap costs no basin.
            Measured on 18 poses of notebook 04's setting (0.25 mm renders, oracle orientation,
            fast mode), mean focal error uncapped / 3 px / 1 px: shipped U-Net 2.3 / 0.67 / 0.45 mm
            (uncapped, one pose 14 mm off and judged implausible), labels with Table I's errors
            0.46 / 0.41 / 0.38 mm; exact labels 0.20 mm at 3 px and at 1 px.
        verdict_truncation_px: the verdict's RMS distance counts each point at most this far
            (None: uncapped), so that stretches of a class the segmentation missed do not fail a
            pose that fits the rest; a wrong pose still has most points beyond it.
        direction_spread_limit_deg: with ``init="robust"`` and two or more views, when the views'
            orientation estimates disagree by more than this (the mean pairwise angle of
            :func:`~histostudy.learning.orientation.select_direction`), one view's estimate is off and
            their mean is off too: the initialisation then also starts from each view's own two
            direction candidates and keeps the lowest-cost start. Estimates with the paper's
            regression errors (1-2 deg) stay well below 15 deg, and their estimates are unchanged;
            a VGG19 that misreads one view by 90 deg no longer sends the pose astray. When the
            views agree but the pose fails the verdict (both misread alike) and ``retry_hypotheses``
            is set, the per-view starts are tried then. ``init.stages["direction_starts"]``
            records how many directions were started from.
    """
    t_start = time.perf_counter()
    frames = _check_frames(frames)
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel, got {type(model).__name__}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if init not in INIT_METHODS:
        raise ValueError(f"init must be one of {INIT_METHODS}, got {init!r}")
    if not (isinstance(direction_spread_limit_deg, (int, float)) and 0 < direction_spread_limit_deg <= 180):
        raise ValueError(f"direction_spread_limit_deg must be a number in (0, 180], got {direction_spread_limit_deg!r}")
    for name, value in (("refine_truncation_px", refine_truncation_px), ("verdict_truncation_px", verdict_truncation_px),
                        ("max_view_disagreement_mm", max_view_disagreement_mm), ("max_body_rms_px", max_body_rms_px),
                        ("max_unexplained_fraction", max_unexplained_fraction)):
        if value is not None and not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be None or a finite number > 0, got {value!r}")
    if distance_maps not in MAP_KINDS:
        raise ValueError(f"distance_maps must be one of {MAP_KINDS}, got {distance_maps!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    segmenter = default_stages()[0] if segmenter is None else segmenter
    orientation = default_stages()[1] if orientation is None else orientation
    timings = {}

    t0 = time.perf_counter()
    labels = [np.asarray(segmenter.segment(f, rng), dtype=np.uint8) for f in frames]
    if largest_component:
        labels = [keep_largest_component(lab) for lab in labels]
    timings["segmentation"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    occlusion_aware = distance_maps == "occlusion_aware"
    maps = [DistanceMaps(f.view, lab, occlusion_aware=occlusion_aware) for f, lab in zip(frames, labels)]
    timings["distance_maps"] = time.perf_counter() - t0
    for f, m in zip(frames, maps):
        if not m.present:
            raise PoseEstimationError(f"view {f.view.name!r}: no transducer feature was segmented; the "
                                      f"transducer is not in this view or the segmentation failed")
    # One flattened copy of the maps; every capped or subset cost below shares it.
    cost = PoseCost(model.points, maps, class_weights=class_weights, outside_distance_px=outside_distance_px)
    refine_cost = cost.capped(refine_truncation_px)
    coarse = cost.subset(init_points_per_class, rng)
    verdict_cost = coarse.capped(verdict_truncation_px)
    consistency_cost = coarse.capped(1.0 if refine_truncation_px is None else refine_truncation_px)
    if init == "robust":
        tau = float(search_truncation_px)
        search = coarse.capped(tau, outside_distance_px=tau)
        # The local refinements' robust cost: the same truncated distances, but eq. 3's own
        # constant for points off the detector. With the truncation as the off-detector cost, a
        # pose that pulls more of the model onto the detector wins over a better-aligned one
        # (measured: a 1-2 mm pull on frames where much of the transducer is outside the view).
        polish_cost = search.with_outside_distance(outside_distance_px)
        tau_coarse = float(coarse_truncation_px)
        # Off the detector a point is unknown. Costing it the full truncation, a pose that pulls
        # more of the model into a view where the transducer is mostly outside can beat the true
        # region; at half the truncation a pose with most of the model off the detectors can
        # beat a near miss of the coarse grid (both measured). Each scoring proposes its chains;
        # the narrower search cost decides after the medium and fine grids.
        # A 3 cm grid needs no more than a few hundred points per class to rank its nodes.
        coarse_scorings = []
        coarse_subset = coarse.subset(max(1, init_points_per_class // 5), rng)
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
            if init == "robust":
                per_view = [c for view_candidates in candidates for c in view_candidates]
                if np.rad2deg(spread) > direction_spread_limit_deg:
                    tries += per_view
                else:
                    deferred_directions = per_view
        if init == "robust":
            def polish(T):
                # Truncated distances: points on missed or hidden features do not pull. Scored by
                # the search cost, so that hypotheses compare as the grids and axial search did.
                r = refine_levenberg_marquardt(polish_cost, T, max_iter=30)
                return r.T, float(search(r.T))
            options = dict(axial_seeds_deg=ROBUST_AXIAL_SEEDS_DEG, fine_after_axial=True, n_hypotheses=3,
                           polish=polish, medium=MEDIUM_GRID, coarse_scorings=coarse_scorings,
                           coarse_candidates=3)
            if len(frames) > 1:
                silhouettes = [lab > 0 for lab in labels]
                body = np.vstack([model.points[k] for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY)
                                  if k in model.points])
                body = body[rng.choice(len(body), size=min(len(body), SILHOUETTE_POINTS), replace=False)]
                centre_local = body.mean(axis=0)
                options["seeded"] = lambda d: [(a, t) for a, t, _ in silhouette_candidates(
                    d, views, silhouettes, body, centre_local_mm=centre_local)]
        else:
            options = dict(axial_seeds_deg=PAPER_AXIAL_SEEDS_DEG, fine_after_axial=False, n_hypotheses=1)
        def start(directions):
            results = [initialise_pose(d, views, view_costs, search, centre_mm=search_centre_mm, **options)
                       for d in directions]
            return min(results, key=lambda r: r.cost), sum(r.n_evaluations for r in results)

        init_result, n_init_eval = start(tries)
        init_result.stages["direction_starts"] = len(tries)
        if len(frames) > 1:
            init_result.stages["direction_spread_deg"] = float(np.rad2deg(spread))
        T_init = init_result.T_carm_transducer
        timings["initialisation"] = time.perf_counter() - t0

    def refine(T0, method=mode):
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

    def judge(T):
        # The verdict's thresholds are coarse (pixels, percent): the point subset judges as well
        # as the whole model at a fraction of the time.
        verdict = judge_fit(verdict_cost, frames, T, search_centre_mm, max_rms_px, min_inside_fraction,
                         max_body_rms_px if occlusion_aware else None)
        if max_unexplained_fraction is not None:
            check_unexplained(verdict, frames, labels, model, T, max_unexplained_fraction,
                               10.0 if verdict_truncation_px is None else verdict_truncation_px)
        if verdict.ok and len(frames) > 1 and max_view_disagreement_mm is not None:
            check_view_agreement(verdict, consistency_cost, frames, T, model.focal_point_mm,
                                  max_view_disagreement_mm)
        return verdict

    t0 = time.perf_counter()
    refined = refine(T_init)
    timings["refinement"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    verdict = judge(refined.T)
    timings["verdict"] = time.perf_counter() - t0
    retries = 0
    if not verdict.ok and init_result is not None and retry_hypotheses:
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
        if not verdict.ok and mode == "fast":
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
                        timings_s=timings, verdict=verdict, mode=mode, init=init_result, refine=refined,
                        labels=labels, retries=retries)
    if not verdict.ok and raise_on_failure:
        raise PoseEstimationError("implausible pose: " + "; ".join(verdict.reasons), verdict, result)
    return result


#: What a shipped network's manifest must show on its validation split before :func:`estimate_pose`
#: uses it by default: a network trained too briefly to be useful (e.g. a VGG19 whose azimuth
#: error is that of a guess, about 90 deg) would otherwise send every default estimate astray.
#: The VGG19 only starts the initialisation's searches, which tolerate large errors: with its
#: per-view direction starts, a VGG19 with validation MAE 25.6 deg azimuth and 11.4 deg elevation
#: (the one shipped before the (cos, sin) regressor) gave the oracle orientation's pose on 16 of 16
#: poses of notebook 04's setting (focal error 0.19 mm either way, oracle labels), hence 30 deg.
LEARNED_STAGE_REQUIREMENTS = {"unet_min_pixel_accuracy": 0.95, "vgg_max_angle_mae_deg": 30.0}


def _validation(stage) -> dict:
    manifest = getattr(stage, "manifest", None) or {}
    return manifest.get("validation", {}) or {}


def learned_stage_shortfalls(segmenter, orientation) -> list[str]:
    """Why these learned stages fall short of :data:`LEARNED_STAGE_REQUIREMENTS` (empty when they meet
    them), judged on their manifests' validation figures; None stands for a missing network."""
    reasons = []
    if segmenter is None:
        reasons.append("no usable shipped U-Net")
    else:
        accuracy = _validation(segmenter).get("pixel_accuracy", float("nan"))
        if not accuracy >= LEARNED_STAGE_REQUIREMENTS["unet_min_pixel_accuracy"]:
            reasons.append(f"the shipped U-Net's validation pixel accuracy {accuracy:.3f} is below "
                           f"{LEARNED_STAGE_REQUIREMENTS['unet_min_pixel_accuracy']}")
    if orientation is None:
        reasons.append("no usable shipped VGG19")
    else:
        v = _validation(orientation)
        worst = max(v.get("azimuth_mae_deg", float("nan")), v.get("elevation_mae_deg", float("nan")))
        if not worst <= LEARNED_STAGE_REQUIREMENTS["vgg_max_angle_mae_deg"]:
            reasons.append(f"the shipped VGG19's validation angle MAE {worst:.1f} deg exceeds "
                           f"{LEARNED_STAGE_REQUIREMENTS['vgg_max_angle_mae_deg']} deg")
    return reasons


@functools.lru_cache(maxsize=1)
def default_stages() -> tuple[Segmenter, OrientationSource]:
    """The segmenter and orientation source :func:`estimate_pose` uses when none is given.

    The learned stages shipped in ``data/models`` (:func:`histostudy.learning.segment.default_segmenter`,
    :func:`histostudy.pose.conic_orientation.default_orientation`) where their weights are present, pass
    their hash and configuration check, and their manifests' validation figures meet
    :data:`LEARNED_STAGE_REQUIREMENTS`; otherwise the oracles (synthetic frames only), with a
    warning that says why. Loaded once per process. Pass ``segmenter=`` / ``orientation=`` to
    :func:`estimate_pose` to choose explicitly (e.g. a network of your own).
    """
    segmenter = default_segmenter()
    orientation = default_orientation(segmenter)  # its conic initialiser reads this U-Net's labels
    reasons = learned_stage_shortfalls(segmenter, orientation)
    if reasons:
        warnings.warn("estimate_pose: " + "; ".join(reasons) + " — using the oracle stages, which need "
                      "synthetic frames", stacklevel=3)
        return OracleSegmenter(), OracleOrientation()
    return segmenter, orientation


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
