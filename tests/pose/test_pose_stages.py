"""Invariants of the staged pose pipeline (histostudy.pose: labels, truncations, directions, start,
refine, verdict, retries, from_labels): :func:`estimate_pose` is its stages, bit for bit, and the
tracker's paths (full-frame warm starts, the fast warm update, the fast from-scratch estimate) are
those same stages.

Frames are the blank-image frames with reference labels of tests/pose/pose_frames.py on the
half-resolution biplane (conftest.py's ``views``); every comparison is exact (``np.array_equal``).
"""

import numpy as np
import pytest
from pose_frames import POSES, frames_of, moved

from histostudy.learning import OracleOrientation, OracleSegmenter, pool_labels
from histostudy.pose import (
    PoseConfig,
    SourceDirections,
    Tracker,
    TrackingConfig,
    apply_left_perturbation,
    estimate_pose,
    estimate_pose_from_labels,
)
from histostudy.pose.labels import clean_labels, segment_frames, view_distance_maps
from histostudy.pose.refine import refine_pose
from histostudy.pose.result import result_of_refinement
from histostudy.pose.retries import refine_with_retries
from histostudy.pose.start import coarse_scorings, initialise
from histostudy.pose.tracking._scratch import _ScaledDirections
from histostudy.pose.truncations import pose_costs
from histostudy.pose.verdict import PoseJudge

STEP = np.eye(4)
STEP[:3, 3] = (0.4, -0.3, 0.2)


def _same(a, b):
    """The poses, costs and verdicts of two results are the same bits."""
    assert np.array_equal(a.T_carm_transducer, b.T_carm_transducer)
    assert np.array_equal(a.focal_point_mm, b.focal_point_mm)
    assert (a.cost, a.iterations, a.evaluations, a.retries, a.mode) == (b.cost, b.iterations, b.evaluations,
                                                                        b.retries, b.mode)
    va, vb = a.verdict, b.verdict
    assert (va.ok, va.reasons, va.rms_distance_px, va.inside_fraction, va.focal_offset_mm, va.view_disagreement_mm,
            va.unexplained_fraction) == (vb.ok, vb.reasons, vb.rms_distance_px, vb.inside_fraction,
                                         vb.focal_offset_mm, vb.view_disagreement_mm, vb.unexplained_fraction)
    assert (a.init is None) == (b.init is None)
    if a.init is not None:
        assert np.array_equal(a.init.T_carm_transducer, b.init.T_carm_transducer)
        assert list(a.init.stages) == list(b.init.stages) and a.init.n_evaluations == b.init.n_evaluations
    assert len(a.labels) == len(b.labels) and all(np.array_equal(x, y) for x, y in zip(a.labels, b.labels))


def _by_hand(frames, views, model, options, seed, initial_pose=None):
    """estimate_pose's stages called one by one, as a user composing them would."""
    rng = np.random.default_rng(seed)
    labels = clean_labels(segment_frames(frames, OracleSegmenter(), rng), views,
                          largest_component=options.largest_component)
    maps = view_distance_maps(views, labels, occlusion_aware=options.distance_maps == "occlusion_aware")
    costs = pose_costs(model.points, maps, options, rng)
    scorings = coarse_scorings(costs, options, len(views), rng)
    initialisation = None
    T_init = initial_pose
    if initial_pose is None:
        directions = SourceDirections(OracleOrientation(), frames)
        candidates = [directions(a, lab, m, rng) for a, (lab, m) in enumerate(zip(labels, maps))]
        initialisation = initialise(candidates, views, labels, model, costs, scorings, options, rng)
        T_init = initialisation.result.T_carm_transducer
    out = refine_with_retries(costs, PoseJudge(costs, views, labels, model, options), T_init, initialisation,
                              options, {})
    return result_of_refinement(out.refine, out.verdict, model.focal_point_mm, mode=options.mode, timings_s={},
                                labels=labels, init=None if initialisation is None else initialisation.result,
                                n_init_evaluations=0 if initialisation is None else initialisation.n_evaluations,
                                retries=out.retries)


@pytest.mark.parametrize("overrides, warm", [
    (dict(mode="fast"), False),
    (dict(mode="fast", init="paper"), False),
    (dict(mode="paper"), True),
])
def test_estimate_pose_is_its_stages_bit_for_bit(models, views, overrides, warm):
    model, fine = models
    frames = frames_of(fine, POSES[1], views)
    start = apply_left_perturbation(POSES[1], [0.01, -0.01, 0.005, 1.0, -0.8, 0.5]) if warm else None
    kwargs = dict(rng=11, initial_pose=start, raise_on_failure=False, **overrides)
    # (the paper's initialisation refuses this pose on the half-resolution views: its retries run too)
    whole = estimate_pose(frames, model, segmenter=OracleSegmenter(), orientation=OracleOrientation(), **kwargs)
    rng = np.random.default_rng(11)
    labels = segment_frames(frames, OracleSegmenter(), rng)
    from_labels = estimate_pose_from_labels(labels, views, model,
                                            orientation=SourceDirections(OracleOrientation(), frames),
                                            **{**kwargs, "rng": rng})
    _same(whole, from_labels)
    _same(whole, _by_hand(frames, views, model, PoseConfig(raise_on_failure=False, **overrides), 11, start))


def test_the_seed_rule_is_one_for_every_entry_point(models, views):
    """rng=None is the fixed seed 0, an int seed its default_rng: estimate_pose and the Tracker agree."""
    model, fine = models
    frames = frames_of(fine, POSES[0], views)
    stages = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation(), mode="fast", raise_on_failure=False)
    unseeded, zero = (estimate_pose(frames, model, rng=rng, **stages) for rng in (None, 0))
    _same(unseeded, zero)
    tracked = Tracker(model, views, fast=False, **stages).update(frames)
    _same(tracked, zero)


def test_the_full_frame_tracker_is_estimate_pose_from_labels_stage_by_stage(models, views):
    model, fine = models
    pairs = [frames_of(fine, T, views) for T in (POSES[0], moved(POSES[0], STEP))]
    stages = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())
    tracker = Tracker(model, views, fast=False, rng=5, mode="fast", **stages)
    tracked = [tracker.update(pair) for pair in pairs]
    assert tracker.last_kind == "warm"
    rng, T = np.random.default_rng(5), None
    for pair, result in zip(pairs, tracked):
        labels = segment_frames(pair, stages["segmenter"], rng)
        direct = estimate_pose_from_labels(labels, views, model,
                                           orientation=SourceDirections(stages["orientation"], pair),
                                           rng=rng, initial_pose=T, mode="fast", raise_on_failure=False)
        _same(result, direct)
        T = direct.T_carm_transducer


def test_the_fast_warm_update_is_the_costs_refine_and_verdict_stages(models, views):
    model, fine = models
    pairs = [frames_of(fine, T, views) for T in (POSES[0], moved(POSES[0], STEP))]
    tracker = Tracker(model, views, rng=3, mode="fast", segmenter=OracleSegmenter(), orientation=OracleOrientation(),
                      fast=TrackingConfig(label_scale=0.5))
    T_prev = tracker.update(pairs[0]).T_carm_transducer
    region = tracker._region
    prepared = region.prepare(pairs[1], T_prev, tracker.rng)
    result = region.finish(prepared, T_prev)
    # the same stages, called directly on the prepared regions
    s = prepared.regions[0].scale
    options = region._scaled_options(s)
    costs = pose_costs(region._refine_points, prepared.maps, options, np.random.default_rng(region._subset_seed),
                       label_scale=s, truncated_search=True)
    refined = refine_pose(costs, T_prev, "fast", xtol_mm=region.tracking.stop_step_mm,
                          xtol_rad=np.deg2rad(region.tracking.stop_step_deg))
    verdict = PoseJudge(costs, [r.view for r in prepared.regions], prepared.labels, model, options, label_scale=s,
                        unexplained_points_mm=region._unexplained_points)(refined.T)
    direct = result_of_refinement(refined, verdict, model.focal_point_mm, mode="fast", timings_s={},
                                  labels=prepared.labels)
    assert result.verdict.ok, result.verdict.reasons
    _same(result, direct)


def test_the_fast_from_scratch_estimate_is_estimate_pose_from_labels_on_pooled_labels(models, views):
    model, fine = models
    frames = frames_of(fine, POSES[0], views)
    tracker = Tracker(model, views, rng=3, mode="fast", segmenter=OracleSegmenter(), orientation=OracleOrientation(),
                      fast=TrackingConfig(scratch_label_scale=0.5))
    scratch = tracker._scratch
    rng = np.random.default_rng(8)
    result = scratch.estimate(frames, np.random.default_rng(8))
    assert scratch.last_step == "scaled" and result.verdict.ok, result.verdict.reasons
    labels = [pool_labels(OracleSegmenter().segment(f, rng), 0.5) for f in frames]
    directions = _ScaledDirections(scratch.orientation, scratch._conics, scratch.views, frames)
    direct = estimate_pose_from_labels(labels, scratch.views, scratch.model, orientation=directions, rng=rng,
                                       options=scratch.options)
    _same(result, direct)
