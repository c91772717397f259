"""Tests of warming a tracker up before a live stream (histostudy.pose.tracking._warm_up,
``Tracker.warm_up``): the synthetic pair's geometry, the whole path run, and the tracker put back
as it was, so that the poses after a warm-up are those of a tracker that never warmed up."""

import numpy as np
import pytest
from pose_frames import POSES, frames_of, moved

from histostudy.geometry import transform_from_params
from histostudy.imaging import default_biplane
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import Tracker, TrackingConfig
from histostudy.pose.tracking._warm_up import views_isocentre_mm, warm_up_pair

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())
SCALED = TrackingConfig(scratch_label_scale=0.5)  # the fast from-scratch path, as the U-Net's


def test_the_isocentre_projects_to_every_detector_centre():
    views = default_biplane()
    iso = views_isocentre_mm(views)
    for view in views:
        rows, cols = view.shape
        np.testing.assert_allclose(view.project(iso[None])[0], [(cols - 1) / 2, (rows - 1) / 2], atol=1e-6)


def test_the_warm_up_pair_shows_the_transducer_in_every_view(models, views):
    model, _ = models
    frames = warm_up_pair(model, views, np.random.default_rng(0))
    assert [f.view for f in frames] == list(views)
    for frame in frames:
        assert frame.image.shape == frame.view.shape and np.isfinite(frame.image).all()
        assert (frame.labels > 0).mean() > 0.05  # the transducer covers a good part of each view
    again = warm_up_pair(model, views, np.random.default_rng(0))
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, again))
    with pytest.raises(ValueError, match="two or more views"):
        warm_up_pair(model, views[:1], np.random.default_rng(0))


def test_a_warmed_up_tracker_gives_the_poses_of_one_that_never_was(models, views):
    model, fine = models
    step = transform_from_params(np.r_[np.deg2rad([0.5, -0.3, 0.4]), [0.6, -0.4, 0.3]])
    stream = [frames_of(fine, T, views) for T in (POSES[0], moved(POSES[0], step), POSES[1])]
    warmed = Tracker(model, views, rng=7, mode="fast", fast=SCALED, **ORACLES)
    report = warmed.warm_up()
    assert report["kinds"] == ["from_scratch", "warm"] and report["accepted"] == [True, True], report
    assert report["seconds"] > 0
    assert warmed.n_updates == 0 and warmed.last_pose is None and warmed.stats()["update_seconds"] == 0
    cold = Tracker(model, views, rng=7, mode="fast", fast=SCALED, **ORACLES)
    for frames in stream:
        a, b = warmed.update(frames), cold.update(frames)
        assert warmed.last_kind == cold.last_kind
        assert np.array_equal(a.T_carm_transducer, b.T_carm_transducer)
    assert {k: v for k, v in warmed.stats().items() if k.startswith("n_")} == \
        {k: v for k, v in cold.stats().items() if k.startswith("n_")}


def test_a_warm_up_in_the_middle_of_a_track_keeps_the_track(models, views):
    model, fine = models
    tracker = Tracker(model, views, rng=2, mode="fast", fast=SCALED, **ORACLES)
    tracker.update(frames_of(fine, POSES[0], views))
    before, counters = tracker.last_pose, tracker.stats()
    tracker.warm_up(frames_of(fine, POSES[1], views))  # the caller's own pair
    assert np.array_equal(tracker.last_pose, before) and tracker.stats() == counters
    tracker.update(frames_of(fine, POSES[0], views))
    assert tracker.last_kind == "warm"
