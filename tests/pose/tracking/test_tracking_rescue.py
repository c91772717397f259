"""Tests of the fast tracker's second warm attempt (TrackingConfig.rescue_scale), of the warm start
resumed from a pose refused for its views' agreement (TrackingConfig.resume_refused), and of
Tracker.track's ``ready`` (a live source whose next pair may not have arrived).

The frames are the blank-image frames with reference labels of tests/pose/pose_frames.py on the
half-resolution biplane; a segmenter reads the labels (the oracle) except where a test spoils one
view's labels once, so that the first warm attempt on the 0.5 grid is refused and the second, on
the same frames segmented again at the detector's resolution, is not.
"""

import numpy as np
import pytest
from pose_frames import POSES, focal_error, frames_of, moved

from histostudy.geometry import transform_from_params
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import PoseConfig, RegionEstimator, Tracker, TrackingConfig

STEP = transform_from_params(np.r_[np.deg2rad(0.2) * np.array([0.6, -0.48, 0.64]), [0.3, -0.25, 0.3]])
#: Plane B's labels are those of a pose 6 mm and 3 deg away: no single pose explains both views.
#: (SHIFT: 2 mm along z, each view fits a pose, the views disagree by about a millimetre.)
SHIFT = transform_from_params([0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
SPOIL = transform_from_params(np.r_[np.deg2rad(3.0) * np.array([0.0, 0.6, 0.8]), [6.0, 0.0, -4.0]])


class SpoiltOnce(OracleSegmenter):
    """The reference labels, except for the next ``n_spoilt`` segmentations of view B: ``spoilt``."""

    def __init__(self, spoilt):
        super().__init__()
        self.spoilt, self.n_spoilt = spoilt, 0

    def segment(self, frame, rng=None):
        if frame.view.name == "B" and self.n_spoilt > 0:
            self.n_spoilt -= 1
            return self.spoilt
        return super().segment(frame, rng)


@pytest.fixture(scope="module")
def stream(models, views):
    """Three frame pairs 0.5 mm and 0.2 deg apart, their poses, and view B's labels at a pose far
    from the third."""
    poses = [POSES[0], moved(POSES[0], STEP), moved(moved(POSES[0], STEP), STEP)]
    spoilt = frames_of(models[1], moved(poses[2], SPOIL), views)[1].labels
    return poses, [frames_of(models[1], T, views) for T in poses], spoilt


@pytest.mark.parametrize("rescue_scale", [1.0, None])
def test_a_refused_warm_start_is_tried_again_at_the_detector_resolution_before_the_track_is_lost(
        models, views, stream, rescue_scale):
    """With the default rescue_scale the refused first attempt is followed by a second on the same
    frames segmented again at scale 1: accepted, a warm update, counted as rescued. Without it the
    track is lost and the frames are estimated from scratch (as before)."""
    poses, frames, spoilt = stream
    segmenter = SpoiltOnce(spoilt)
    tracker = Tracker(models[0], views, rng=3, mode="fast", segmenter=segmenter, orientation=OracleOrientation(),
                      fast=TrackingConfig(label_scale=0.5, rescue_scale=rescue_scale))
    for pair in frames[:2]:
        assert tracker.update(pair).verdict.ok
    assert tracker.last_kind == "warm" and tracker.n_rescue_attempts == 0
    segmenter.n_spoilt = 1  # the first attempt's segmentation of view B only
    result = tracker.update(frames[2])
    assert result.verdict.ok and focal_error(result, poses[2]) < 0.2
    stats = tracker.stats()
    if rescue_scale is None:
        assert tracker.last_kind == "reacquired" and result.init is not None
        assert (stats["n_rescue_attempts"], stats["n_rescued"], stats["n_lost"], stats["n_reacquired"]) == (0, 0, 1, 1)
        return
    assert tracker.last_kind == "warm" and result.init is None
    assert (stats["n_rescue_attempts"], stats["n_rescued"], stats["n_lost"], stats["n_warm"]) == (1, 1, 0, 2)
    # the second attempt's regions: the first's boxes at the detector's pixels
    regions = tracker.last_regions
    assert [r.scale for r in regions] == [1.0, 1.0]
    assert [lab.shape for lab in result.labels] == [r.view.shape for r in regions]
    r0, r1, c0, c1 = regions[1].box
    np.testing.assert_array_equal(result.labels[1], frames[2][1].labels[r0:r1, c0:c1])
    # every update is counted once: warm, or from scratch (the first)
    assert stats["n_updates"] == stats["n_warm"] + stats["n_from_scratch"] == 3
    assert stats["n_accepted"] == 3 and stats["stage_seconds"]["total"] <= stats["update_seconds"]


def test_a_second_attempt_the_verdict_refuses_too_loses_the_track(models, views, stream):
    """Spoilt in both attempts: the track is lost after the second, and the re-acquisition, on the
    reference labels, finds the pose."""
    poses, frames, spoilt = stream
    segmenter = SpoiltOnce(spoilt)
    tracker = Tracker(models[0], views, rng=3, mode="fast", segmenter=segmenter, orientation=OracleOrientation(),
                      fast=TrackingConfig(label_scale=0.5))
    tracker.update(frames[1])
    segmenter.n_spoilt = 2
    result = tracker.update(frames[2])
    assert tracker.last_kind == "reacquired" and result.verdict.ok and focal_error(result, poses[2]) < 0.2
    assert (tracker.n_rescue_attempts, tracker.n_rescued, tracker.n_lost, tracker.n_reacquired) == (1, 0, 1, 1)


@pytest.mark.parametrize("resume", [True, False])
def test_a_pose_refused_for_its_views_agreement_is_resumed_warm_on_the_next_pair(models, views, stream, resume):
    """The first estimate sees plane B's labels 2 mm off: it fits each view, and the views disagree
    beyond a limit of 0.5 mm (the test's, to make the case). The next pair, consistent, starts warm
    from the refused pose and is accepted; with resume_refused=False it is estimated from scratch."""
    poses, frames, _ = stream
    segmenter = SpoiltOnce(frames_of(models[1], moved(poses[1], SHIFT), views)[1].labels)
    segmenter.n_spoilt = 1
    tracker = Tracker(models[0], views, rng=3, mode="fast", segmenter=segmenter, orientation=OracleOrientation(),
                      max_view_disagreement_mm=0.5, retry_hypotheses=False,
                      fast=TrackingConfig(label_scale=0.5, resume_refused=resume))
    first = tracker.update(frames[1])
    assert not first.verdict.ok and first.verdict.view_disagreement_mm
    assert all("the views disagree" in reason for reason in first.verdict.reasons)
    assert not tracker.tracking and tracker.last_kind == "from_scratch"
    second = tracker.update(frames[2])
    assert second.verdict.ok and focal_error(second, poses[2]) < 0.2
    stats = tracker.stats()
    if resume:
        assert tracker.last_kind == "warm" and second.init is None
        assert (stats["n_resume_attempts"], stats["n_resumed"], stats["n_from_scratch"]) == (1, 1, 1)
    else:
        assert tracker.last_kind == "from_scratch" and second.init is not None
        assert (stats["n_resume_attempts"], stats["n_resumed"], stats["n_from_scratch"]) == (0, 0, 2)
    assert stats["n_updates"] == stats["n_warm"] + stats["n_from_scratch"] and stats["n_lost"] == 0


def test_no_second_attempt_where_the_labels_are_at_the_detector_resolution_already(models, views):
    estimator = RegionEstimator(models[0], views, OracleSegmenter(), PoseConfig(mode="fast"), TrackingConfig(),
                                np.random.default_rng(0))
    assert estimator.label_scale == 1.0 and estimator.rescue_scale is None
    half = RegionEstimator(models[0], views, OracleSegmenter(), PoseConfig(mode="fast"),
                           TrackingConfig(label_scale=0.25, rescue_scale=0.5), np.random.default_rng(0))
    assert half.rescue_scale == 0.5
    with pytest.raises(ValueError, match="rescue_scale is None: this estimator makes no second attempt"):
        estimator.prepare_rescue(None, None)


def test_bad_rescue_options_are_refused_naming_the_argument(models, views):
    for bad in (1, None, "yes"):
        with pytest.raises(ValueError, match="resume_refused must be True or False"):
            TrackingConfig(resume_refused=bad)
    for bad in (0.3, 2.0, 0.0, -0.5, float("nan"), "1", True):
        with pytest.raises(ValueError, match=r"rescue_scale must be None or 1/k for an integer k >= 1"):
            TrackingConfig(rescue_scale=bad)
    # label pixels of a third of a frame pixel: boxes on multiples of 3 px hold no whole 2 px pixel
    with pytest.raises(ValueError, match=r"rescue_scale 0.5: the regions' corners lie on multiples of 3"):
        RegionEstimator(models[0], views, OracleSegmenter(), PoseConfig(mode="fast"),
                        TrackingConfig(label_scale=1 / 3, rescue_scale=0.5), np.random.default_rng(0))


def test_track_with_ready_takes_no_pair_ahead_and_raises_a_bad_pair_at_its_turn(models, views, stream):
    """``ready`` False: each pair is posed before the next is taken (the source sees no pull ahead),
    with the poses of update(); a bad pair taken ahead is raised only after the pairs before it."""
    poses, frames, _ = stream
    taken = []

    def source(pairs):
        for i, pair in enumerate(pairs):
            taken.append(i)
            yield pair

    oracles = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())
    stepwise = Tracker(models[0], views, rng=4, mode="fast", fast=True, **oracles)
    expected = [stepwise.update(pair) for pair in frames]
    live = Tracker(models[0], views, rng=4, mode="fast", fast=True, **oracles)
    for i, result in enumerate(live.track(source(frames), ready=lambda: False)):
        assert taken == list(range(i + 1))  # nothing taken ahead of the pair just posed
        np.testing.assert_allclose(result.T_carm_transducer, expected[i].T_carm_transducer, atol=1e-9)
    ahead = Tracker(models[0], views, rng=4, mode="fast", fast=True, **oracles)
    results = []
    with pytest.raises(ValueError, match="frames must hold one frame per view"):
        for result in ahead.track([frames[0], frames[1], frames[2][:1]]):
            results.append(result)
    assert len(results) == 2 and ahead.n_updates == 2 and all(r.verdict.ok for r in results)
