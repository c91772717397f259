"""Tests of the tracker's fast warm path (histostudy.pose.tracking._warm, Tracker(fast=...)).

Geometry first: with the oracle stages (exact labels) on the half-resolution biplane views, the
fast path's poses must stay within 0.1 mm of the full-frame path's on a small moving sequence, at
label scale 1 (the labels cropped) and 1/2 (pooled by priority, the shipped U-Net's resolution).
"""

import numpy as np
import pytest
from pose_frames import POSES, assert_jump_reacquired, focal_error, frames_of, moved

from histostudy.geometry import transform_from_params
from histostudy.imaging import Frame
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import PoseConfig, PoseEstimationError, RegionEstimator, Tracker, TrackingConfig

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())
STEP = transform_from_params(np.r_[np.deg2rad(0.2) * np.array([0.6, -0.48, 0.64]), [0.3, -0.25, 0.3]])





@pytest.fixture(scope="module")
def sequence(models, views):
    """Four frame pairs of a transducer moving 0.5 mm and 0.2 deg a frame, with their poses."""
    poses = [POSES[0]]
    for _ in range(3):
        poses.append(moved(poses[-1], STEP))
    return poses, [frames_of(models[1], T, views) for T in poses]


@pytest.fixture(scope="module")
def full_frame_poses(models, views, sequence):
    tracker = Tracker(models[0], views, fast=False, rng=3, mode="fast", **ORACLES)
    return [tracker.update(f).T_carm_transducer for f in sequence[1]]


@pytest.mark.parametrize("label_scale", [1.0, 0.5])
def test_fast_warm_path_stays_within_0_1_mm_of_the_full_frame_path(models, views, sequence, full_frame_poses,
                                                                    label_scale):
    poses, frames = sequence
    tracker = Tracker(models[0], views, rng=3, mode="fast", fast=TrackingConfig(label_scale=label_scale), **ORACLES)
    for i, (pair, T_true, T_full) in enumerate(zip(frames, poses, full_frame_poses)):
        result = tracker.update(pair)
        assert result.verdict.ok, result.verdict.reasons
        assert tracker.last_kind == ("from_scratch" if i == 0 else "warm")
        focal_gap = np.linalg.norm(result.T_carm_transducer[:3, 3] - T_full[:3, 3])
        assert focal_gap < 0.1, (i, focal_gap)
        assert focal_error(result, T_true) < 0.2
    regions = tracker.last_regions
    assert [r.scale for r in regions] == [label_scale] * 2
    assert [lab.shape for lab in result.labels] == [r.view.shape for r in regions]
    assert all(r.area_fraction < 1.0 for r in regions)  # the transducer does not fill these frames
    assert result.init is None and result.timings_s["orientation"] == result.timings_s["initialisation"] == 0.0
    assert (tracker.n_warm, tracker.n_from_scratch, tracker.n_lost) == (3, 1, 0)


def test_a_jump_loses_the_fast_track_and_is_reacquired_and_counted(models, views):
    """The transducer moved 16 mm and turned between two frames: the fast warm start from the last
    pose fails its verdict, the full frames are estimated from scratch, and the track goes on fast.
    (A 40-80 mm shift alone is followed: the coarse stage's 30 px cap pulls the model along.)"""
    model, fine = models
    T0, T_jump = POSES[0], POSES[1]
    tracker = Tracker(model, views, rng=2, mode="fast", fast=True, **ORACLES)
    assert_jump_reacquired(tracker, fine, views, T0, T_jump, moved(T_jump, STEP))
    tracker.reset()
    assert tracker.last_regions is None and not tracker.tracking


def test_a_region_without_features_raises_for_the_tracker_to_reacquire(models, views):
    model, fine = models
    estimator = RegionEstimator(model, views, OracleSegmenter(), PoseConfig(mode="fast"), TrackingConfig(),
                                np.random.default_rng(0))
    blank = [Frame(np.zeros(v.shape, np.float32), v, labels=np.zeros(v.shape, np.uint8)) for v in views]
    with pytest.raises(PoseEstimationError, match="no transducer feature was segmented in the tracking region"):
        estimator.estimate(blank, POSES[0], np.random.default_rng(0))


def test_the_same_seed_gives_the_same_fast_track(models, views, sequence):
    runs = []
    for _ in range(2):
        tracker = Tracker(models[0], views, rng=9, mode="fast", fast=True, **ORACLES)
        runs.append([tracker.update(f).T_carm_transducer for f in sequence[1][:2]])
    np.testing.assert_array_equal(np.array(runs[0]), np.array(runs[1]))


def test_the_default_tracker_is_the_fast_one(models, views, sequence):
    """Tracker(model, views) runs the region path with TrackingConfig()'s defaults: the poses of
    fast=True, bit for bit; fast=False is the full-frame path, with no region estimator."""
    default = Tracker(models[0], views, rng=6, mode="fast", **ORACLES)
    explicit = Tracker(models[0], views, rng=6, mode="fast", fast=True, **ORACLES)
    assert default.tracking_options == TrackingConfig() == explicit.tracking_options
    for pair in sequence[1][:2]:
        np.testing.assert_array_equal(default.update(pair).T_carm_transducer, explicit.update(pair).T_carm_transducer)
    assert default.last_kind == "warm" and default.last_regions is not None
    full = Tracker(models[0], views, rng=6, fast=False, **ORACLES)
    assert full.tracking_options is None and full._region is None


def test_bad_fast_options_are_refused_naming_the_argument(models, views):
    with pytest.raises(TypeError, match="fast must be True, False or a histostudy.pose.TrackingConfig"):
        Tracker(models[0], views, fast="yes", **ORACLES)
    with pytest.raises(ValueError, match="roi_margin_px must be"):
        TrackingConfig(roi_margin_px=-5)
    with pytest.raises(ValueError, match="label_scale must be None or 1/k"):
        TrackingConfig(label_scale=0.4)
    with pytest.raises(ValueError, match="refine_points_per_class must be None or a positive integer"):
        TrackingConfig(refine_points_per_class=0)
    with pytest.raises(ValueError, match="stop_step_mm must be"):
        TrackingConfig(stop_step_mm=0)
    with pytest.raises(ValueError, match="parallel_views must be True or False"):
        TrackingConfig(parallel_views=1)
    with pytest.raises(ValueError, match="precision must be one of"):
        TrackingConfig(precision="float16")


def test_track_overlaps_the_stages_and_gives_the_poses_of_update(models, views, sequence):
    """Tracker.track prepares each pair's regions on a worker thread from the pose one pair older:
    the same kinds, counters and (within a hundredth of a millimetre) the same poses as update()."""
    poses, frames = sequence
    stepwise = Tracker(models[0], views, rng=4, mode="fast", fast=True, **ORACLES)
    expected = [stepwise.update(pair) for pair in frames]
    streamed = Tracker(models[0], views, rng=4, mode="fast", fast=True, **ORACLES)
    results = list(streamed.track(iter(frames)))
    assert len(results) == len(frames)
    for a, b in zip(results, expected):
        assert a.verdict.ok and np.linalg.norm(a.focal_point_mm - b.focal_point_mm) < 0.01
    assert streamed.stats()["n_warm"] == stepwise.stats()["n_warm"] == len(frames) - 1
    plain = Tracker(models[0], views, fast=False, rng=4, mode="fast", **ORACLES)  # without fast: update in a loop
    assert [r.verdict.ok for r in plain.track(frames[:2])] == [True, True] and plain.n_updates == 2


def test_track_reacquires_after_a_jump_and_stops_on_bad_input(models, views):
    model, fine = models
    stream = [frames_of(fine, T, views) for T in (POSES[0], POSES[1], moved(POSES[1], STEP))]
    tracker = Tracker(model, views, rng=2, mode="fast", fast=True, **ORACLES)
    kinds = []
    for result in tracker.track(stream):
        kinds.append(tracker.last_kind)
        assert result.verdict.ok
    assert kinds == ["from_scratch", "reacquired", "warm"]
    assert (tracker.n_lost, tracker.n_reacquired, tracker.n_warm) == (1, 1, 1)
    with pytest.raises(ValueError, match="frames must hold one frame per view"):
        list(tracker.track([stream[0], stream[0][:1]]))


@pytest.mark.parametrize("overrides, reach", [({}, 15.0),
                                              ({"search_truncation_px": 20.0, "verdict_truncation_px": 24.0}, 12.0),
                                              ({"refine_truncation_px": None}, None),
                                              ({"verdict_truncation_px": None}, None)])
def test_region_maps_are_exact_up_to_the_largest_cap_they_are_read_at(models, views, sequence, overrides, reach):
    from histostudy.pose import DistanceMaps

    poses, frames = sequence
    options = PoseConfig(**overrides)
    estimator = RegionEstimator(models[0], views, OracleSegmenter(), options, TrackingConfig(label_scale=0.5),
                                np.random.default_rng(0))
    prepared = estimator.prepare(frames[1], poses[0], np.random.default_rng(1))
    for region, labels, maps in zip(prepared.regions, prepared.labels, prepared.maps):
        exact = DistanceMaps(region.view, labels, occlusion_aware=True)
        for feature in exact.present:
            expected = exact.maps[feature] if reach is None else np.minimum(exact.maps[feature], np.float32(reach))
            np.testing.assert_array_equal(maps.maps[feature], expected)


def test_prepare_gives_the_same_regions_with_the_views_in_turn_or_on_two_threads(models, views, sequence):
    poses, frames = sequence
    estimator = RegionEstimator(models[0], views, OracleSegmenter(), PoseConfig(), TrackingConfig(label_scale=0.5),
                                np.random.default_rng(0))
    both = [estimator.prepare(frames[1], poses[0], np.random.default_rng(1), slot, parallel)
            for slot, parallel in ((0, True), (1, False))]
    for a in range(len(views)):
        assert both[0].regions[a].box == both[1].regions[a].box
        np.testing.assert_array_equal(both[0].labels[a], both[1].labels[a])
        for feature in both[0].maps[a].present:
            np.testing.assert_array_equal(both[0].maps[a].maps[feature], both[1].maps[a].maps[feature])
    with pytest.raises(ValueError, match="parallel_views"):
        estimator.prepare(frames[1], poses[0], None, 0, "yes")
