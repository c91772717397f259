"""Frames segmented once for the estimates that share them (a pose's variants, stage sets, the error
budget's configurations and labs): :class:`SegmentationCache`, exact for segmenters that draw and
for those that do not.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np

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
        if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
            raise ValueError(f"max_frames must be an integer >= 1, got {max_frames!r}")
        self.segmenter = segmenter
        self.uses_rng = getattr(segmenter, "uses_rng", True)  # the wrapped segmenter's (learning.Segmenter)
        self.max_frames = max_frames
        self.hits = self.misses = 0
        self._labels: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def segment(self, frame, rng: np.random.Generator | None = None) -> np.ndarray:
        """The labels of ``frame`` (``segmenter.segment(frame, rng)``), once per distinct call."""
        if self.uses_rng and not isinstance(rng, np.random.Generator):
            return self.segmenter.segment(frame, rng)
        digest = hashlib.blake2b(np.ascontiguousarray(frame.image).tobytes())
        if frame.labels is not None:
            digest.update(np.ascontiguousarray(frame.labels).tobytes())
        key = (frame.image.shape, digest.hexdigest(), repr(rng.bit_generator.state) if self.uses_rng else None)
        with self._lock:
            entry = self._labels.get(key)
            if entry is not None:
                self.hits += 1
                self._labels.move_to_end(key)
        if entry is not None:
            labels, state = entry
            if self.uses_rng:
                rng.bit_generator.state = state
            return labels.copy()
        labels = np.asarray(self.segmenter.segment(frame, rng))
        with self._lock:
            self.misses += 1
            self._labels[key] = (labels.copy(), rng.bit_generator.state if self.uses_rng else None)
            while len(self._labels) > self.max_frames:
                self._labels.popitem(last=False)
        return labels
