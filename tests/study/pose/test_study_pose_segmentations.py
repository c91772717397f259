"""Frames segmented once (study.pose.segmentations.SegmentationCache): the labels and draws of
calling the segmenter each time, for segmenters that draw and for those that do not."""

import numpy as np
import pytest

from histostudy.imaging import Frame, default_biplane
from histostudy.study.pose.segmentations import SegmentationCache


class _Segmenter:
    """The image thresholded, at a drawn level (``uses_rng``) or at a fixed one; counts its calls."""

    def __init__(self, uses_rng: bool):
        self.uses_rng, self.calls = uses_rng, 0

    def segment(self, frame, rng):
        self.calls += 1
        level = rng.uniform(0.0, 0.1) if self.uses_rng else 0.05
        return (frame.image > level).astype(np.uint8)


def _frame(seed: int) -> Frame:
    view = default_biplane()[0].scaled(0.125)
    return Frame(np.random.default_rng(seed).uniform(0, 0.1, view.shape).astype(np.float32), view)


def test_a_drawing_segmenter_is_called_once_per_frame_and_generator_state():
    inner, frame = _Segmenter(True), _frame(1)
    cache = SegmentationCache(inner)
    rngs = [np.random.default_rng(7) for _ in range(3)]
    labels = [cache.segment(frame, rng) for rng in rngs[:2]]
    direct = _Segmenter(True).segment(frame, rngs[2])
    assert np.array_equal(labels[0], direct) and np.array_equal(labels[1], direct)
    assert rngs[0].random() == rngs[1].random() == rngs[2].random()  # each left where the call leaves it
    assert (inner.calls, cache.hits, cache.misses) == (1, 1, 1)
    cache.segment(frame, np.random.default_rng(8))
    assert inner.calls == 2  # another Generator state: segmented again
    labels[0][:] = 9  # a caller's change does not reach the cache
    assert np.array_equal(cache.segment(frame, np.random.default_rng(7)), direct)


def test_a_segmenter_that_draws_nothing_is_called_once_per_frame_content():
    inner = _Segmenter(False)
    cache = SegmentationCache(inner, max_frames=1)
    assert cache.uses_rng is False
    frame, rng = _frame(1), np.random.default_rng(3)
    state = rng.bit_generator.state
    first = cache.segment(frame, rng)
    again = cache.segment(Frame(frame.image.copy(), frame.view), np.random.default_rng(99))  # same content
    assert inner.calls == 1 and np.array_equal(first, again) and rng.bit_generator.state == state
    cache.segment(_frame(2), None)
    cache.segment(frame, None)  # pushed out by the other frame (max_frames=1): segmented again
    assert (inner.calls, cache.hits, cache.misses) == (3, 1, 3)


@pytest.mark.parametrize("bad", [0, 2.0, True])
def test_a_cache_of_no_frames_is_refused(bad):
    with pytest.raises(ValueError, match="max_frames must be an integer >= 1"):
        SegmentationCache(_Segmenter(False), bad)
