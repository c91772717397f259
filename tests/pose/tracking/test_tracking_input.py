"""Tests of histostudy.pose.tracking._input.frames_for_views: the frame pairs a Tracker accepts."""

import numpy as np
import pytest

from histostudy.imaging import Frame, default_biplane
from histostudy.pose.tracking._input import frames_for_views


def test_arrays_become_frames_of_their_views_and_frames_of_other_views_are_refused():
    views = [v.scaled(0.25) for v in default_biplane()]
    images = np.random.default_rng(0).random((2, *views[0].shape)).astype(np.float32)
    frames = frames_for_views(images, views)
    assert [f.view for f in frames] == views
    np.testing.assert_array_equal(frames[1].image, images[1])
    assert frames_for_views(frames, views)[0] is frames[0]
    swapped = [Frame(images[0], views[1]), Frame(images[1], views[0])]
    with pytest.raises(ValueError, match=r"frames\[0\] was taken with view"):
        frames_for_views(swapped, views)
    with pytest.raises(ValueError, match="one frame per view, 2"):
        frames_for_views(images[:1], views)
    with pytest.raises(ValueError, match="got a single Frame"):
        frames_for_views(frames[0], views)
    with pytest.raises(ValueError, match=r"frames\[1\] has shape \(3, 4\)"):
        frames_for_views([images[0], np.zeros((3, 4))], views)
