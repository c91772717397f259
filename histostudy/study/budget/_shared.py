"""Work shared between runs of one experiment whose frames are alike (the budget's configurations,
the labs): a frame rendered and segmented once per distinct input and Generator state, the
Generator left where the first call left it, so every run gets its own numbers (exact).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
from collections import OrderedDict
from collections.abc import Iterator

import numpy as np

from histostudy.imaging import shared_frames

__all__ = ["SharedSegmentations", "shared_work"]


class SharedSegmentations:
    """A segmenter that segments each distinct frame once: a frame with the same image and
    reference labels, met with the Generator in the same state, gets the labels of the first call
    and the Generator is set where that call left it (the numbers the wrapped ``segmenter`` gives).
    The ``max_frames`` most recently used are kept; ``hits`` and ``misses`` count the calls."""

    def __init__(self, segmenter, max_frames: int = 32):
        if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
            raise ValueError(f"max_frames must be an integer >= 1, got {max_frames!r}")
        self.segmenter = segmenter
        self.uses_rng = getattr(segmenter, "uses_rng", True)  # the wrapped segmenter's (learning.Segmenter)
        self.max_frames = max_frames
        self.hits = self.misses = 0
        self._labels: OrderedDict = OrderedDict()

    def segment(self, frame, rng: np.random.Generator | None = None) -> np.ndarray:
        """The labels of ``frame`` (``segmenter.segment(frame, rng)``), once per distinct call."""
        if not isinstance(rng, np.random.Generator):
            return self.segmenter.segment(frame, rng)
        digest = hashlib.blake2b(np.ascontiguousarray(frame.image).tobytes())
        if frame.labels is not None:
            digest.update(np.ascontiguousarray(frame.labels).tobytes())
        key = (frame.image.shape, digest.hexdigest(), repr(rng.bit_generator.state))
        if key in self._labels:
            self.hits += 1
            self._labels.move_to_end(key)
            labels, state = self._labels[key]
            rng.bit_generator.state = state
            return labels.copy()
        self.misses += 1
        labels = np.asarray(self.segmenter.segment(frame, rng))
        self._labels[key] = (labels.copy(), rng.bit_generator.state)
        while len(self._labels) > self.max_frames:
            self._labels.popitem(last=False)
        return labels


@contextlib.contextmanager
def shared_work(setup, config, *, max_frames: int = 32) -> Iterator[tuple]:
    """A scope for the runs of one experiment: yields ``(setup', frames, segmentations)``, the
    set-up (a :class:`~._run.BudgetSetup`) with its segmenter (``config.segmenter()`` where it has
    none, as the studies default) wrapped in :class:`SharedSegmentations`, the active
    :class:`~histostudy.imaging.render._memo.FrameMemo` and the wrapper; ``max_frames`` bounds each."""
    segmenter = setup.segmenter if setup.segmenter is not None else config.segmenter()
    segmentations = SharedSegmentations(segmenter, max_frames)
    with shared_frames(max_frames) as frames:
        yield dataclasses.replace(setup, segmenter=segmentations), frames, segmentations
