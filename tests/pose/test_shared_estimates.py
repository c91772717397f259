"""Estimates shared within a scope (pose.shared_estimates): a repeated call is the call's own
result, to the bit, with the Generator left where the call leaves it; anything that differs is
estimated again."""

import numpy as np
import pytest
from pose_frames import POSES, frames_of

from histostudy.imaging import Frame, default_biplane
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import PoseEstimationError, estimate_pose, shared_estimates
from histostudy.transducer import TransducerModel

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())


@pytest.fixture(scope="module")
def models():
    return TransducerModel.build(spacing_mm=0.47), TransducerModel.build(spacing_mm=0.25)


@pytest.fixture(scope="module")
def frames(models):
    return frames_of(models[1], POSES[0])


def test_a_repeated_estimate_is_the_estimate_and_leaves_the_generator_alike(models, frames):
    plain_rng = np.random.default_rng(4)
    plain = estimate_pose(frames, models[0], rng=plain_rng, mode="fast", **ORACLES)
    with shared_estimates() as memo:
        rngs = [np.random.default_rng(4) for _ in range(2)]
        first = estimate_pose(frames, models[0], rng=rngs[0], mode="fast", **ORACLES)
        first.T_carm_transducer[:] = 0.0  # a caller's change does not reach the memo
        second = estimate_pose([f.with_view(f.view) for f in frames], models[0], rng=rngs[1], mode="fast", **ORACLES)
        assert (memo.misses, memo.hits) == (1, 1)
        np.testing.assert_array_equal(second.T_carm_transducer, plain.T_carm_transducer)
        assert second.cost == plain.cost and second.verdict.ok == plain.verdict.ok
        assert rngs[0].random() == rngs[1].random() == plain_rng.random()  # the Generator where the call left it

        estimate_pose(frames, models[0], rng=np.random.default_rng(5), mode="fast", **ORACLES)  # another state
        estimate_pose(frames, models[0], rng=np.random.default_rng(4), mode="paper", **ORACLES)  # another option
        estimate_pose(frames, models[0], rng=np.random.default_rng(4), mode="fast", segmenter=OracleSegmenter(),
                      orientation=ORACLES["orientation"])  # an equal segmenter, but another object
        moved = [Frame(f.image, f.view, labels=np.roll(f.labels, 1, axis=1), T_carm_transducer=f.T_carm_transducer)
                 for f in frames]
        estimate_pose(moved, models[0], rng=np.random.default_rng(4), mode="fast", **ORACLES)  # other labels
        estimate_pose(frames, models[0], rng=4, mode="fast", **ORACLES)  # an int seed: not compared
        assert (memo.misses, memo.hits, len(memo)) == (5, 1, 5)
    outside = estimate_pose(frames, models[0], rng=np.random.default_rng(4), mode="fast", **ORACLES)
    np.testing.assert_array_equal(outside.T_carm_transducer, plain.T_carm_transducer)


def test_a_refusal_is_raised_again_and_the_memo_keeps_the_latest(models):
    views = default_biplane()
    empty = [Frame(np.zeros(v.shape, np.float32), v, labels=np.zeros(v.shape, np.uint8)) for v in views]
    with shared_estimates(max_estimates=1) as memo:
        for _ in range(2):
            with pytest.raises(PoseEstimationError, match="view 'A': no transducer feature"):
                estimate_pose(empty, models[0], rng=np.random.default_rng(1), **ORACLES)
        assert (memo.misses, memo.hits) == (1, 1)
        with pytest.raises(PoseEstimationError):
            estimate_pose(empty, models[0], rng=np.random.default_rng(2), **ORACLES)
        assert len(memo) == 1 and memo.misses == 2


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "8"])
def test_a_memo_of_no_estimates_is_refused(bad):
    with pytest.raises(ValueError, match="max_estimates must be an integer >= 1"), shared_estimates(bad):
        pass
