"""The pipeline of :meth:`~._tracker.Tracker.track` with ``fast`` (docs/tracking.md):
:func:`pipelined_updates`.

Two stages on two threads: while the calling thread refines and judges a pair
(:meth:`~._warm.RegionEstimator.finish`, the cost's kernels serial meanwhile), one worker thread
segments and maps the next pair's regions (:meth:`~._warm.RegionEstimator.prepare`, its
views one after the other) from the last pose accepted before it. Torch, OpenCV and the cost's
kernels release the GIL, so on two cores each stage has one. On the cines of docs/tracking.md this
gives more warm pairs per second than the same stages one after the other (the figures are there).

Implementation of :class:`~._tracker.Tracker`'s method: it reads and updates the tracker's state
(its last pose, its Generator, its counters through ``Tracker._update``).
"""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, Iterator

import numpy as np

from ..result import PoseResult
from ._input import frames_for_views

__all__ = []  # Tracker.track is the public entry point

_END = object()  # the end of a stream


@dataclasses.dataclass(frozen=True)
class _BadPair:
    """A pair of the stream taken ahead whose check failed: raised at its turn."""

    error: ValueError


def pipelined_updates(tracker, pairs: Iterable, ready: Callable[[], bool] | None) -> Iterator[PoseResult]:
    """:meth:`~._tracker.Tracker.track`'s results for a tracker with ``fast`` (its docstring says what
    they are; the module docstring how they are made)."""
    source = iter(pairs)

    def take():
        # the next pair, checked; a bad one is raised when its turn comes, not ahead of it
        item = next(source, _END)
        if item is _END:
            return _END
        try:
            return frames_for_views(item, tracker.views)
        except ValueError as exc:
            return _BadPair(exc)

    worker = ThreadPoolExecutor(max_workers=1)
    pending = None
    try:
        nxt = take()
        slot = 0  # the map buffers of the pair being finished; the next pair is prepared in the other
        while True:
            if nxt is None:
                nxt = take()
            if nxt is _END:
                break
            frames, prepared_future = nxt, pending
            pending = nxt = None
            if isinstance(frames, _BadPair):
                raise frames.error
            if ready is None or ready():
                nxt = take()
            if nxt is not None and nxt is not _END and not isinstance(nxt, _BadPair) \
                    and tracker._last_pose is not None:
                # A segmenter that draws gets its own Generator, seeded here: nothing is drawn
                # from the tracker's on the worker thread.
                rng = None if tracker._region.fast_unet is not None else \
                    np.random.default_rng(int(tracker.rng.integers(2 ** 63)))
                # The views one after the other: the pairs already overlap, and two more threads
                # on two cores cost pairs per second (docs/tracking.md).
                pending = worker.submit(tracker._region.prepare, nxt, tracker._last_pose.copy(), rng, 1 - slot, False)
            t_start = time.perf_counter()
            prepared = None if prepared_future is None else prepared_future.result()
            # While the worker segments the next pair, serial kernels here: numba's threads would
            # take its core (16.7-17.5 warm pairs/s against 13.5-17.3, docs/tracking.md).
            result = tracker._update(frames, prepared, t_start, slot, parallel=False if pending is not None else None)
            if pending is not None and tracker.last_kind != "warm":
                pending.result()  # prepared from a pose the track has since left: prepare again
                pending = None
            slot = 1 - slot
            yield result
    finally:
        if pending is not None:
            pending.cancel()
        worker.shutdown(wait=True)
