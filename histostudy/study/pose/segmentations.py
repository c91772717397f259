"""Frames segmented once for the estimates that share them (a pose's variants, stage sets, the error
budget's configurations and labs): :class:`SegmentationCache`, exact for segmenters that draw and
for those that do not.
"""

from __future__ import annotations

import numpy as np

from histostudy.core import GeneratorMemo, check_count, value_digest

__all__ = ["SegmentationCache"]


class SegmentationCache:
    """A :class:`~histostudy.learning.Segmenter` that segments each distinct frame once.

    A segmenter whose labels depend on the frame alone (``uses_rng = False``, as
    :class:`~histostudy.learning.UNetRunner`) is asked once per frame content (image and reference
    labels) whatever the Generator; one that draws (the oracle's Table I degradation) once per
    frame content and Generator state, and a repeat sets the Generator where the first call left
    it. Either way the labels and draws are those of calling the wrapped ``segmenter`` each time.
    The ``max_frames`` most recently used are kept; ``hits`` and ``misses`` count the calls.

    Args:
        segmenter: the segmenter wrapped (``segment(frame, rng) -> labels``).
        max_frames: how many frames' labels are kept, an integer >= 1.

    Raises:
        ValueError: ``max_frames`` is not an integer >= 1.
    """

    def __init__(self, segmenter, max_frames: int = 32):
        self.max_frames = check_count(max_frames, "max_frames")
        self.segmenter = segmenter
        self.uses_rng = getattr(segmenter, "uses_rng", True)  # the wrapped segmenter's (learning.Segmenter)
        self._memo = GeneratorMemo(max_frames)

    @property
    def hits(self) -> int:
        """Calls answered from the cache."""
        return self._memo.hits

    @property
    def misses(self) -> int:
        """Calls the wrapped segmenter answered."""
        return self._memo.misses

    def segment(self, frame, rng: np.random.Generator | None = None) -> np.ndarray:
        """The labels of ``frame`` (``segmenter.segment(frame, rng)``), once per distinct call."""
        if self.uses_rng and not isinstance(rng, np.random.Generator):
            return self.segmenter.segment(frame, rng)
        key = value_digest((frame.image, frame.labels))
        return self._memo.call(key, lambda: np.asarray(self.segmenter.segment(frame, rng)),
                               rng=rng if self.uses_rng else None, copy_result=_copy_labels)


def _copy_labels(labels: object) -> np.ndarray:
    assert isinstance(labels, np.ndarray)  # the memo copies only what segment() computed, an np.asarray
    return np.copy(labels)
