"""Tests of the tracker's fast from-scratch estimate at the label scale (histostudy.pose.tracking._scratch,
``TrackingConfig.scratch_label_scale``; docs/tracking.md "From scratch in under a second").

Geometry first, with the oracle stages (reference labels pooled by priority) on the half-resolution
views; then the shipped U-Net and conic/VGG19 orientation on a rendered full-size pair, against the
truth and against the full-frame path (:func:`estimate_pose` on the detector's pixels).
"""

import dataclasses

import numpy as np
import pytest
from pose_frames import POSES, focal_error, frames_of

from histostudy.imaging import default_biplane, random_background, render_frame
from histostudy.learning import OracleOrientation, OracleSegmenter, default_segmenter
from histostudy.pose import PoseConfig, Tracker, TrackingConfig, default_stages
from histostudy.pose.tracking._options import PIXEL_OPTIONS
from histostudy.pose.tracking._scratch import ScratchEstimator, scaled_pose_options

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())


def test_oracle_labels_at_half_scale_give_the_full_frame_pose(models, views):
    model, fine = models
    frames = frames_of(fine, POSES[0], views)
    full = Tracker(model, views, rng=3, mode="fast", fast=True, **ORACLES)  # scale 1 for an oracle segmenter
    assert full._scratch is None
    reference = full.update(frames)
    tracker = Tracker(model, views, rng=3, mode="fast", fast=TrackingConfig(scratch_label_scale=0.5), **ORACLES)
    result = tracker.update(frames)
    assert tracker.last_kind == "from_scratch" and result.verdict.ok, result.verdict.reasons
    assert result.init is not None and [lab.shape for lab in result.labels] == [(240, 310)] * 2
    # measured: 0.07 mm from the truth, 0.07 mm from the full-frame pose (0.01 mm from the truth)
    assert focal_error(result, POSES[0]) < 0.15
    assert np.linalg.norm(result.focal_point_mm - reference.focal_point_mm) < 0.15
    assert result.timings_s["segmentation"] > 0 and result.timings_s["total"] >= sum(
        result.timings_s[k] for k in ("segmentation", "distance_maps", "orientation", "initialisation"))


def test_a_pose_refused_at_the_label_scale_is_judged_again_on_the_full_frames(models, views):
    model, fine = models
    frames = frames_of(fine, POSES[1], views)
    tracker = Tracker(model, views, rng=4, mode="fast", fast=TrackingConfig(scratch_label_scale=0.5), **ORACLES)
    estimator = tracker._scratch
    # an RMS limit no pose meets at the label scale: step 1 is refused, step 2 (full frames, from its pose) holds
    estimator.options = dataclasses.replace(estimator.options, max_rms_px=1e-9)
    result = tracker.update(frames)
    assert estimator.last_step == "full_frame_warm" and result.verdict.ok, result.verdict.reasons
    assert result.init is not None and [lab.shape for lab in result.labels] == [v.shape for v in views]
    assert focal_error(result, POSES[1]) < 0.15
    stages = ("segmentation", "distance_maps", "orientation", "initialisation", "refinement", "verdict")
    assert result.timings_s["total"] >= sum(result.timings_s[k] for k in stages)
    # refused on the full frames too: estimated from scratch there (without retries, which would all fail)
    estimator.full_options = dataclasses.replace(estimator.full_options, max_rms_px=1e-9, retry_hypotheses=False)
    tracker.reset()
    result = tracker.update(frames)
    assert estimator.last_step == "full_frame" and not result.verdict.ok and result.init is not None


def test_without_the_full_frames_a_pose_refused_at_the_label_scale_is_the_result(models, views):
    """scratch_full_frames=False (the live receiver's): one step at the label scale, its refused pose
    returned as it is, with no step on the full frames."""
    model, fine = models
    frames = frames_of(fine, POSES[1], views)
    live = TrackingConfig(scratch_label_scale=0.5, scratch_full_frames=False)
    tracker = Tracker(model, views, rng=4, mode="fast", fast=live, **ORACLES)
    estimator = tracker._scratch
    estimator.options = dataclasses.replace(estimator.options, max_rms_px=1e-9)
    result = tracker.update(frames)
    assert estimator.last_step == "scaled" and not result.verdict.ok and result.init is not None
    assert [lab.shape for lab in result.labels] == [(v.shape[0] // 2, v.shape[1] // 2) for v in views]
    assert focal_error(result, POSES[1]) < 0.5  # the refusal is the impossible RMS limit's, not the pose's
    with pytest.raises(ValueError, match="scratch_full_frames must be True or False"):
        TrackingConfig(scratch_full_frames="no")


def test_pixel_options_are_scaled_and_the_rest_kept():
    options = PoseConfig(mode="fast", max_body_rms_px=None)
    scaled = scaled_pose_options(options, 0.5)
    for field in PoseConfig.field_names():
        before, after = getattr(options, field), getattr(scaled, field)
        if field in PIXEL_OPTIONS and before is not None:
            assert after == pytest.approx(0.5 * before), field
        else:
            assert after == before, field
    for bad in (0, 1.5, float("nan"), True):
        with pytest.raises(ValueError, match="scale must be a number in \\(0, 1\\]"):
            scaled_pose_options(options, bad)


@pytest.mark.parametrize("value", [0.3, 0.0, -0.5, 2.0, "half", True])
def test_bad_scratch_label_scales_are_refused_naming_the_field(value):
    with pytest.raises(ValueError, match="scratch_label_scale must be None or 1/k"):
        TrackingConfig(scratch_label_scale=value)


def test_a_scale_the_unet_cannot_give_is_refused(models):
    segmenter = default_segmenter()
    if segmenter is None:
        pytest.skip("the shipped U-Net (data/models/unet_standard) is not available")
    views = default_biplane()
    with pytest.raises(ValueError, match="scratch_label_scale 0.333.* U-Net's input scale 0.5"):
        Tracker(models[0], views, rng=0, fast=TrackingConfig(scratch_label_scale=1 / 3), segmenter=segmenter,
                orientation=OracleOrientation())
    odd = [dataclasses.replace(v, shape=(v.shape[0] - 1, v.shape[1])) for v in views]
    with pytest.raises(ValueError, match=r"views\[0\] shape \(959, 1240\) is not divisible"):
        ScratchEstimator(models[0], odd, segmenter.with_precision("auto"), OracleOrientation(), PoseConfig(),
                         TrackingConfig(), 0.5, np.random.default_rng(0))


@pytest.fixture(scope="module")
def rendered_pair(models):
    """A full-size biplane pair (the U-Net's frame size) of the 0.47 mm model on a phantom scene."""
    if default_segmenter() is None:
        pytest.skip("the shipped learned stages (data/models) are not available")
    orientation = default_stages()[1]
    rng = np.random.default_rng(31)
    scene = random_background(rng, "phantom")
    views = default_biplane()
    T = POSES[1]
    return views, T, [render_frame(models[0], T, v, rng=rng, background=scene) for v in views], orientation


def test_the_shipped_stages_at_half_scale_match_the_truth_and_the_full_frames(models, rendered_pair):
    views, T, frames, orientation = rendered_pair
    full = Tracker(models[0], views, rng=7, mode="fast", fast=TrackingConfig(scratch_label_scale=1),
                   orientation=orientation)
    reference = full.update(frames)
    tracker = Tracker(models[0], views, rng=7, mode="fast", fast=True, orientation=orientation)
    assert tracker._scratch.scale == 0.5 and full._scratch is None
    result = tracker.update(frames)
    assert tracker.last_kind == "from_scratch" and result.verdict.ok, result.verdict.reasons
    assert reference.verdict.ok, reference.verdict.reasons
    # measured: 0.28 mm from the truth (the full-frame path 0.44 mm), 0.17 mm apart
    assert focal_error(result, T) < 0.5
    assert np.linalg.norm(result.focal_point_mm - reference.focal_point_mm) < 0.4
    assert [lab.shape for lab in result.labels] == [(480, 620)] * 2
    # the track goes on warm from it
    tracker.update(frames)
    assert tracker.last_kind == "warm" and tracker.n_from_scratch == 1
    # the same seed gives the same pose
    again = Tracker(models[0], views, rng=7, mode="fast", fast=True, orientation=orientation).update(frames)
    np.testing.assert_array_equal(again.T_carm_transducer, result.T_carm_transducer)
