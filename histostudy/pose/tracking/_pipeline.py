"""The pipeline of :meth:`~._tracker.Tracker.track` with ``fast``: pair n refined and judged on the
calling thread while pair n+1's views are segmented on a worker thread (:func:`pipelined_updates`;
docs/tracking.md, "The pipeline of Tracker.track").
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from ..result import PoseResult
from ._input import frames_for_views
from ._warm import PreparedRegions, RegionPlan

__all__ = []  # Tracker.track is the public entry point

_END = object()  # the end of a stream


@dataclasses.dataclass(frozen=True)
class _BadPair:
    """A pair of the stream taken ahead whose check failed: raised at its turn."""

    error: ValueError


def pipelined_updates(tracker, pairs: Iterable, ready: Callable[[], bool] | None) -> Iterator[PoseResult]:
    """:meth:`~._tracker.Tracker.track`'s results for a tracker with ``fast`` (its docstring says what
    they are; docs/tracking.md how they are made)."""
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

    region = tracker._region
    worker = ThreadPoolExecutor(max_workers=1)
    pending: tuple[RegionPlan, list[Future[tuple]]] | None = None  # the next pair's plan and its views' tasks
    try:
        nxt = take()
        slot = 0  # the map buffers of the pair being finished; the next pair is prepared in the other
        while True:
            if nxt is None:
                nxt = take()
            if nxt is _END:
                break
            frames, prepared_tasks = nxt, pending
            pending = nxt = None
            if isinstance(frames, _BadPair):
                raise frames.error
            if ready is None or ready():
                nxt = take()
            if nxt is not None and nxt is not _END and not isinstance(nxt, _BadPair) \
                    and tracker._last_pose is not None:
                plan = region.plan(nxt, tracker._last_pose.copy(), _worker_rng(tracker), 1 - slot)
                pending = (plan, [worker.submit(region.prepare_view, plan, a) for a in range(len(nxt))])
            t_start = time.perf_counter()
            prepared: PreparedRegions | None = None if prepared_tasks is None else _collect(region, *prepared_tasks)
            # While the worker segments the next pair, serial kernels here: numba's threads would
            # take its core (docs/tracking.md).
            result = tracker._update(frames, prepared, t_start, slot, parallel=False if pending is not None else None)
            if pending is not None and tracker.last_kind != "warm":
                _drop(pending[1])  # prepared from a pose the track has since left: prepared again
                pending = None
            slot = 1 - slot
            yield result
    finally:
        if pending is not None:
            _drop(pending[1])
        worker.shutdown(wait=True)


def _worker_rng(tracker) -> list | None:
    """A segmenter that draws gets a Generator per view, seeded here: nothing is drawn from the
    tracker's on the worker thread, and the views draw the same numbers whichever thread runs
    them (None for a U-Net, which draws nothing)."""
    if tracker._region.fast_unet is not None:
        return None
    seed = int(tracker.rng.integers(2 ** 63))
    return [np.random.default_rng([seed, a]) for a in range(len(tracker.views))]


def _collect(region, plan, tasks):
    """The plan's :class:`~._warm.PreparedRegions`: each view task the worker has not started is
    taken back and run on this thread, then the started ones are awaited."""
    outputs = {a: region.prepare_view(plan, a) for a, task in enumerate(tasks) if task.cancel()}
    outputs.update({a: task.result() for a, task in enumerate(tasks) if a not in outputs})
    return region.assemble(plan, [outputs[a] for a in range(len(tasks))])


def _drop(tasks) -> None:
    """Cancel the tasks not started and wait for the others (their map buffers are reused next)."""
    for task in tasks:
        if not task.cancel():
            task.exception()
