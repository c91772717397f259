"""Tests of histostudy.pose.Tracker: estimate_pose warm-started from the last accepted pose.

Frames are blank images with reference labels (tests/pose/pose_frames.py) on the biplane views at
half resolution, read by the oracle stages, so each estimate takes a fraction of a second.
"""

import numpy as np
import pytest
from pose_frames import POSES, assert_jump_reacquired, focal_error, frames_of, moved

from histostudy.geometry import rotation_angle, transform_from_params
from histostudy.imaging import Frame
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import ConicOrientation, PoseEstimationError, Tracker, estimate_pose

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())

#: A small move between two frames of a stream: 1 deg about a tilted axis, 0.8 mm.
SMALL_MOVE = transform_from_params([0.01, -0.012, 0.008, 0.5, -0.4, 0.5])





def test_warm_start_gives_the_from_scratch_pose_at_less_cost(models, views):
    model, fine = models
    T0, T1 = POSES[0], moved(POSES[0], SMALL_MOVE)
    tracker = Tracker(model, views, fast=False, rng=1, **ORACLES)
    first = tracker.update(frames_of(fine, T0, views))
    assert tracker.last_kind == "from_scratch" and first.verdict.ok and first.init is not None
    assert tracker.tracking and focal_error(first, T0) < 0.1
    warm = tracker.update(frames_of(fine, T1, views))
    assert tracker.last_kind == "warm" and warm.verdict.ok and warm.init is None
    scratch = estimate_pose(frames_of(fine, T1, views), model, rng=np.random.default_rng(1), **ORACLES)
    assert np.linalg.norm(warm.focal_point_mm - scratch.focal_point_mm) < 0.1
    angle = np.rad2deg(rotation_angle(warm.T_carm_transducer[:3, :3].T @ scratch.T_carm_transducer[:3, :3]))
    assert min(angle, 180.0 - angle) < 0.1  # up to the transducer's half-turn symmetry
    # cheaper: no orientation, no search, fewer cost evaluations
    assert warm.evaluations < scratch.evaluations / 2, (warm.evaluations, scratch.evaluations)
    assert warm.timings_s["orientation"] == warm.timings_s["initialisation"] == 0.0
    np.testing.assert_allclose(tracker.last_pose, warm.T_carm_transducer)
    stats = tracker.stats()
    assert (stats["n_updates"], stats["n_warm"], stats["n_from_scratch"], stats["n_lost"], stats["n_accepted"]) \
        == (2, 1, 1, 0, 2)
    assert stats["stage_seconds"]["total"] == pytest.approx(first.timings_s["total"] + warm.timings_s["total"])
    assert stats["update_seconds"] >= stats["stage_seconds"]["total"]


def test_a_jump_loses_the_track_and_is_reacquired_on_the_same_frames(models, views):
    """A 40 mm jump between frames: the warm start fails its verdict (the model is pushed off the
    views), the same frames are estimated from scratch, and the track goes on warm."""
    model, fine = models
    T0 = POSES[0]
    T_jump = T0.copy()
    T_jump[:3, 3] += [40.0, 0.0, 0.0]
    tracker = Tracker(model, views, fast=False, rng=2, **ORACLES)
    assert_jump_reacquired(tracker, fine, views, T0, T_jump, moved(T_jump, SMALL_MOVE))


class ImageLabels:
    """A segmenter for the test: the image holds the label values (a stand-in that, like a learned
    segmenter, reads the pixels and nothing else of the frame)."""

    def segment(self, frame, rng=None):
        return np.rint(frame.image).astype(np.uint8)


def test_arrays_and_frames_give_the_same_poses_for_the_same_seed(models, views):
    model, fine = models
    stages = dict(segmenter=ImageLabels(), orientation=ConicOrientation(segmenter=ImageLabels()))
    images = [[f.labels.astype(np.float32) for f in frames_of(fine, T, views)]
              for T in (POSES[1], moved(POSES[1], SMALL_MOVE))]
    with_frames, with_arrays, stacked = (Tracker(model, views, fast=False, rng=5, **stages) for _ in range(3))
    for pair in images:
        a = with_frames.update([Frame(image, v) for image, v in zip(pair, views)])
        b = with_arrays.update(pair)
        c = stacked.update(np.stack(pair))  # (n_views, rows, cols): one image per view
        assert a.verdict.ok and focal_error(a, POSES[1]) < 2.0
        np.testing.assert_array_equal(a.T_carm_transducer, b.T_carm_transducer)
        np.testing.assert_array_equal(a.T_carm_transducer, c.T_carm_transducer)
    assert with_frames.last_kind == with_arrays.last_kind == "warm"


def test_no_feature_raises_and_loses_the_track(models, views):
    model, fine = models
    tracker = Tracker(model, views, fast=False, rng=0, **ORACLES)
    tracker.update(frames_of(fine, POSES[0], views))
    blank = [Frame(np.zeros(v.shape, np.float32), v, labels=np.zeros(v.shape, np.uint8),
                   T_carm_transducer=POSES[0]) for v in views]
    with pytest.raises(PoseEstimationError, match="no transducer feature"):
        tracker.update(blank)
    assert not tracker.tracking and tracker.last_pose is None
    assert (tracker.n_updates, tracker.n_lost, tracker.n_failed, tracker.n_accepted) == (2, 1, 1, 1)


def test_a_failed_verdict_is_returned_or_raised_as_asked(models, views):
    """The default returns the failed verdict (a stream goes on); raise_on_failure=True raises it."""
    model, fine = models
    # labels of two different poses: no single pose explains both views
    contradicting = frames_of(fine, POSES[0], views, labels_pose=[None, POSES[1]])
    tracker = Tracker(model, views, fast=False, rng=0, mode="fast", retry_hypotheses=False, **ORACLES)
    result = tracker.update(contradicting)
    assert not result.verdict.ok and not tracker.tracking and tracker.n_failed == 1
    strict = Tracker(model, views, fast=False, rng=0, mode="fast", retry_hypotheses=False, raise_on_failure=True,
                     **ORACLES)
    with pytest.raises(PoseEstimationError, match="implausible pose") as err:
        strict.update(contradicting)
    assert err.value.result is not None and strict.n_failed == 1


def test_bad_input_is_refused_naming_the_argument(models, views):
    model, fine = models
    tracker = Tracker(model, views, fast=False, rng=0, **ORACLES)
    frames = frames_of(fine, POSES[0], views)
    with pytest.raises(ValueError, match=r"frames must hold one frame per view, 2 \('A', 'B'\), got 1"):
        tracker.update(frames[:1])
    with pytest.raises(ValueError, match=r"frames must hold one frame per view, 2 .*got 3"):
        tracker.update(frames + frames[:1])
    with pytest.raises(ValueError, match=r"frames\[1\] has shape \(960, 1240\); view 'B' \(views\[1\]\) expects "
                                         r"\(480, 620\)"):
        tracker.update([np.zeros(views[0].shape), np.zeros((960, 1240))])
    with pytest.raises(ValueError, match=r"frames\[0\] must be a Frame or a 2-D numeric array"):
        tracker.update([np.zeros((2,) + views[0].shape), np.zeros(views[1].shape)])
    with pytest.raises(ValueError, match=r"frames\[0\] was taken with view"):
        tracker.update(frames[::-1])
    with pytest.raises(ValueError, match=r"frames\[1\]: image must be finite"):
        tracker.update([np.zeros(views[0].shape), np.full(views[1].shape, np.nan)])
    with pytest.raises(ValueError, match="got a single Frame"):
        tracker.update(frames[0])
    assert tracker.n_updates == 0  # nothing ran
    with pytest.raises(TypeError, match="model must be"):
        Tracker("model", views)
    with pytest.raises(ValueError, match="views must hold at least one View"):
        Tracker(model, [])
    with pytest.raises(TypeError, match=r"views\[1\] must be a histostudy.imaging.View"):
        Tracker(model, [views[0], "B"])
    with pytest.raises(TypeError, match="unexpected keyword argument 'speed'"):
        Tracker(model, views, speed=2, **ORACLES)
    with pytest.raises(ValueError, match="mode must be one of"):
        Tracker(model, views, mode="quick", **ORACLES)
    with pytest.raises(TypeError, match="rng must be"):
        Tracker(model, views, rng="seed", **ORACLES)


def test_add_timings_sums_stage_by_stage_and_takes_new_stages():
    from histostudy.pose.result import add_timings

    sums = {}
    add_timings(sums, {"segmentation": 0.25, "total": 1.0})
    add_timings(sums, {"segmentation": np.float64(0.5), "retries": 2, "total": 0.5})
    assert sums == {"segmentation": 0.75, "total": 1.5, "retries": 2.0}
    assert all(type(v) is float for v in sums.values())
