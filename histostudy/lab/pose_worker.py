"""The pose worker of the live receiver (§II-A): the thread that takes the waiting biplane pairs,
converts their pixels, poses them through :meth:`histostudy.pose.Tracker.track` and writes each pair's
line (:class:`PoseWorker`, a base class of :class:`~.receiver.FrameReceiver`; docs/receiver.md).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from histostudy.pose import PoseResult, Tracker, half_turn_reading
from histostudy.transducer import TransducerModel

from .pairing import PlaneFrame
from .pose_lines import PoseLineFile, pose_line
from .receiver_counts import ReceiverCounts
from .xray_objects import PendingFrame, ReceivedFrame, XRayObjectRejected

__all__: list[str] = []  # the receiver's internals: FrameReceiver is the public face

log = logging.getLogger("histostudy.lab.receiver")  # the receiver's log, where its users look

#: A pair taken by the worker: ``(index, frames, queued_at, taken_at)``, its frames' pixels converted.
_Taken = tuple[int, list[ReceivedFrame], float, float]
#: A pair whose line is due: as :data:`_Taken`, or with its frames unconverted where their pixels failed.
_Due = tuple[int, Sequence[ReceivedFrame | PendingFrame], float, float]


class PoseWorker:
    """The pose worker's methods of :class:`~.receiver.FrameReceiver` (its base class; module
    docstring): :meth:`_work` is the thread's target."""

    # set by FrameReceiver.__init__ (and _out by its start, before the worker runs)
    warm_up: bool
    pipeline: bool
    tracker: Tracker
    model: TransducerModel
    air_value: float | None
    on_pose: Callable[[dict], object] | None
    _cv: threading.Condition
    _queue: collections.deque[tuple[int, tuple[PlaneFrame, ...], float]]
    _closing: bool
    _max_pairs: int | None
    _stats: ReceiverCounts
    _counts: collections.Counter[str]
    _out: PoseLineFile | None
    _t_free: float

    def _warm_up_tracker(self) -> None:
        """:meth:`histostudy.pose.Tracker.warm_up` with ``warm_up``, its seconds in the stats; a
        warm-up that raises is logged and left: the first pair then pays what it would have."""
        if not self.warm_up:
            return
        try:
            report = self.tracker.warm_up()
            half_turn_reading(np.eye(4), self.model)  # the pose lines' symmetry check, once per model
        except Exception as exc:
            log.warning("tracker warm-up failed (%s: %s); the first pair will compile and build what it needs",
                        type(exc).__name__, exc)
            return
        with self._cv:
            self._stats.warm_up_s = report["seconds"]
        log.info("tracker warmed up in %.1f s (%s)", report["seconds"],
                 ", ".join(f"{kind} {'accepted' if ok else 'refused'}"
                           for kind, ok in zip(report["kinds"], report["accepted"])))

    def _work(self) -> None:
        """Pose the queued pairs through ``Tracker.track`` until closing leaves none; a pair whose
        pose raised gets its error line, and the stream goes on in a new ``track``."""
        handed: collections.deque[_Taken] = collections.deque()  # taken by the tracker, line not yet written
        again: collections.deque[_Taken] = collections.deque()   # taken by a track() that ended on an error

        def ready() -> bool:  # take the next pair ahead: it is there, and the pipeline is on
            return self.pipeline and (bool(again) or (bool(self._queue) and not self._at_limit(len(handed))))

        while True:
            results = self.tracker.track(self._pairs(handed, again), ready=ready)
            try:
                for result in results:
                    self._write(handed.popleft(), result, None)
                return  # closing, nothing left to pose
            except Exception as exc:  # one pair's failure is a line, not the end of the stream
                entry = handed.popleft()
                log.warning("pair %d: no pose: %s: %s", entry[0], type(exc).__name__, exc)
                self._write(entry, None, exc)
                again.extend(handed)
                handed.clear()

    def _pairs(self, handed: collections.deque[_Taken], again: collections.deque[_Taken]
               ) -> Iterator[list[np.ndarray]]:
        """The pairs' images for the tracker, in order (a generator that waits for the queue and ends
        once closing with none left); each entry taken goes to ``handed`` first. A pair's pixels are
        converted here, when taken: a pair whose pixels cannot be used gets its error line at once."""
        while True:
            entry: _Taken | None
            if again:
                entry = again.popleft()
            else:
                with self._cv:
                    # wait for a pair unless max_pairs lines are written or on their way
                    while not self._queue or self._at_limit(len(handed)):
                        if self._closing:
                            return
                        self._cv.wait()
                    index, pair, queued_at = self._queue.popleft()
                entry = self._decode(index, [f.data for f in pair], queued_at)
                if entry is None:
                    continue
            handed.append(entry)
            yield [f.image for f in entry[1]]

    def _decode(self, index: int, pending: list[PendingFrame], queued_at: float) -> _Taken | None:
        """The entry ``(index, frames, queued_at, taken_at)`` of a pair taken, its frames' pixels
        converted (:meth:`.xray_objects.PendingFrame.decode`); None when they cannot be, after
        writing the pair's error line (the C-STORE was answered long before: the line says why)."""
        taken_at = time.perf_counter()
        try:
            frames = [f.decode(self.air_value) for f in pending]
        except XRayObjectRejected as exc:
            log.warning("pair %d: its pixels cannot be used (0x%04X): %s", index, exc.status, exc.reason)
            self._write((index, pending, queued_at, taken_at), None, exc)
            return None
        with self._cv:
            self._stats.decode_s += time.perf_counter() - taken_at
        return index, frames, queued_at, taken_at

    def _at_limit(self, in_flight: int = 0) -> bool:
        return self._max_pairs is not None and self._counts["pairs_processed"] + in_flight >= self._max_pairs

    def _write(self, entry: _Due, result: PoseResult | None, error: BaseException | None) -> None:
        """Write the line of ``entry`` (its result, or the ``error`` its pose or its pixels raised),
        count it, call ``on_pose``."""
        index, frames, queued_at, taken_at = entry
        record = pose_line(index, frames, queued_at, taken_at, result=result, error=error,
                           tracking=None if error is not None else self.tracker.last_kind, t_free=self._t_free,
                           t_written=time.perf_counter(), model=self.model)
        assert self._out is not None
        self._out.append(record)
        now = time.perf_counter()
        with self._cv:
            # a snapshot of the tracker's counters: stats() reads it from other threads
            self._stats.add_line(record, self.tracker.stats(), now)
            self._cv.notify_all()
        if self.on_pose is not None:
            try:
                self.on_pose(record)
            except Exception:
                log.exception("on_pose raised on pair %d; the receiver goes on", index)
        self._t_free = time.perf_counter()  # on_pose's time is no pair's pose time
