"""Biplane frames paired by acquisition time (§II-A, §II-D): which frame of plane B was taken with
which frame of plane A (:class:`BiplanePairer`; the frames' times from their tags, :func:`frame_times`;
the rule in docs/receiver.md, "Pairing").
"""

from __future__ import annotations

import bisect
import datetime as _dt
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from histostudy.core.checks import check_count, check_positive, is_finite_real

__all__ = ["BiplanePairer", "DEFAULT_FRAME_INTERVAL_S", "Pairing", "PlaneFrame", "frame_times", "posix_seconds"]

#: The frame interval assumed for single-frame objects (no FrameTime): 15 frames/s, the XA
#: writer's default cine rate (:func:`histostudy.imaging.io._xa.xa_dataset`).
DEFAULT_FRAME_INTERVAL_S = 0.0667

_EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)


@dataclass(frozen=True)
class PlaneFrame:
    """One frame of one plane, as far as pairing goes.

    Attributes:
        plane: the plane (view) name, e.g. ``"A"``.
        time_s: acquisition time, float seconds since the POSIX epoch (see :func:`frame_times`).
        interval_s: the frame interval of its cine (s), None for a single frame.
        data: anything the caller attaches (the receiver: the image and where it came from).
    """

    plane: str
    time_s: float
    interval_s: float | None = None
    data: Any = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        if not isinstance(self.plane, str):
            raise TypeError(f"plane must be a str (a view name), got {type(self.plane).__name__}: {self.plane!r}")
        if not is_finite_real(self.time_s):
            raise ValueError(f"time_s must be a finite time in seconds, got {self.time_s!r}")
        check_positive(self.interval_s, "interval_s", optional=True, what="a finite interval > 0 s")


@dataclass
class Pairing:
    """What one :meth:`BiplanePairer.add` produced: ``sets`` completed (each a tuple with one frame
    per plane, in the pairer's plane order), and the frames ``dropped`` as unpaired."""

    sets: list = field(default_factory=list)
    dropped: list = field(default_factory=list)


class BiplanePairer:
    """Groups frames of ``planes`` into sets taken at the same time (the module docstring's rule).

    Args:
        planes: the plane names, in the order of the sets it emits (the receiver: its views'
            names); unique. One plane: every frame is a set of its own.
        tolerance_s: the largest time difference (exclusive) of two frames of a set; None: half
            the frames' interval (the shorter of two cines' ``FrameTime``; ``default_interval_s``
            for single frames).
        default_interval_s: the interval assumed for a frame without one.
        max_pending: the most unpaired frames kept per plane; beyond, the oldest is dropped.

    Counters: ``n_added``, ``n_sets``, ``n_dropped``. Not thread-safe: the caller locks.
    """

    def __init__(self, planes: Sequence[str], *, tolerance_s: float | None = None,
                 default_interval_s: float = DEFAULT_FRAME_INTERVAL_S, max_pending: int = 64):
        if isinstance(planes, str):
            raise TypeError(f"planes must be a sequence of plane names, got the str {planes!r}")
        planes = tuple(planes)
        if not planes or not all(isinstance(p, str) for p in planes):
            raise ValueError(f"planes must be a non-empty sequence of plane names (str), got {planes!r}")
        if len(set(planes)) != len(planes):
            raise ValueError(f"planes must be unique names, got {planes!r}")
        check_positive(tolerance_s, "tolerance_s", optional=True, what="a finite time > 0 s")
        check_positive(default_interval_s, "default_interval_s", what="a finite interval > 0 s")
        max_pending = check_count(max_pending, "max_pending")
        self.planes = planes
        self.tolerance_s = None if tolerance_s is None else float(tolerance_s)
        self.default_interval_s = float(default_interval_s)
        self.max_pending = max_pending
        # per plane: pending frames sorted by time, and the latest time seen
        self._pending: dict[str, list[PlaneFrame]] = {p: [] for p in planes}
        self._latest: dict[str, float] = {}
        self.n_added = self.n_sets = self.n_dropped = 0

    def tolerance(self, a: PlaneFrame, b: PlaneFrame | None = None) -> float:
        """The largest time difference (s, exclusive) for ``a`` and ``b`` to form a set."""
        if self.tolerance_s is not None:
            return self.tolerance_s
        intervals = [f.interval_s for f in (a, b) if f is not None and f.interval_s is not None]
        return 0.5 * (min(intervals) if intervals else self.default_interval_s)

    def add(self, frame: PlaneFrame) -> Pairing:
        """Add one frame; returns the sets it completed (at most one) and the frames dropped."""
        if not isinstance(frame, PlaneFrame):
            raise TypeError(f"frame must be a PlaneFrame, got {type(frame).__name__}")
        if frame.plane not in self._pending:
            raise ValueError(f"frame.plane must be one of {self.planes}, got {frame.plane!r}")
        self.n_added += 1
        out = Pairing()
        self._latest[frame.plane] = max(self._latest.get(frame.plane, -math.inf), frame.time_s)
        partners = {}
        for plane in self.planes:
            if plane == frame.plane:
                continue
            # the nearest frame of that plane within the tolerance
            best = min((f for f in self._pending[plane] if abs(f.time_s - frame.time_s) < self.tolerance(frame, f)),
                       key=lambda f: abs(f.time_s - frame.time_s), default=None)
            if best is None:
                break
            partners[plane] = best
        if len(partners) == len(self.planes) - 1:
            for plane, partner in partners.items():
                self._pending[plane].remove(partner)
            partners[frame.plane] = frame
            out.sets.append(tuple(partners[p] for p in self.planes))
            self.n_sets += 1
        else:
            pending = self._pending[frame.plane]
            bisect.insort(pending, frame, key=lambda f: f.time_s)
            while len(pending) > self.max_pending:
                out.dropped.append(pending.pop(0))
        out.dropped.extend(self._drop_stale())
        self.n_dropped += len(out.dropped)
        return out

    def _drop_stale(self) -> list[PlaneFrame]:
        """Pending frames no future frame can complete: some other plane's frames have moved past
        them by the tolerance, and none of its pending frames matches them."""
        dropped: list[PlaneFrame] = []
        for plane, pending in self._pending.items():
            keep: list[PlaneFrame] = []
            for f in pending:
                stale = any(self._latest.get(q, -math.inf) - f.time_s >= self.tolerance(f)
                            and not any(abs(g.time_s - f.time_s) < self.tolerance(f, g) for g in self._pending[q])
                            for q in self.planes if q != plane)
                (dropped if stale else keep).append(f)
            pending[:] = keep
        return dropped

    def pending(self) -> dict[str, int]:
        """How many frames wait for a partner, per plane."""
        return {p: len(v) for p, v in self._pending.items()}

    def flush(self) -> list[PlaneFrame]:
        """Every frame still waiting (now dropped as unpaired), oldest first."""
        out = sorted((f for v in self._pending.values() for f in v), key=lambda f: f.time_s)
        for v in self._pending.values():
            v.clear()
        self.n_dropped += len(out)
        return out


def frame_times(ds) -> tuple[list[_dt.datetime], float | None]:
    """The acquisition time of each frame of a DICOM XA/RF object and its cine's frame interval.

    Args:
        ds: a pydicom ``Dataset`` (a single frame, a cine with ``NumberOfFrames``, or an enhanced
            multi-frame object).

    Returns:
        ``(times, interval_s)``: one ``datetime`` per frame (with the object's UTC offset where it
        gives one, else naive), and the frame interval in seconds: the shortest step between two
        frames, so that the pairing tolerance (half of it) never reaches a neighbouring frame (None
        for a single frame).
        :func:`posix_seconds` turns a time into the float seconds :class:`PlaneFrame` takes.

    Raises ValueError naming the attribute and its tag when the object has no usable time.
    """
    n = _number_of_frames(ds)
    per_frame = _per_frame_times(ds, n)
    if per_frame is not None:
        steps = [(b - a).total_seconds() for a, b in zip(per_frame, per_frame[1:])]
        positive = [s for s in steps if s > 0]
        return per_frame, (min(positive) if positive else None)
    start = _start_time(ds)
    if n == 1:
        return [start], None
    offsets_ms = _cine_offsets_ms(ds, n)
    interval_s = min(b - a for a, b in zip(offsets_ms, offsets_ms[1:])) / 1000.0
    return [start + _dt.timedelta(milliseconds=o) for o in offsets_ms], interval_s


def posix_seconds(t: _dt.datetime) -> float:
    """``t`` as float seconds since the POSIX epoch; a naive time is read as UTC (see the module)."""
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.UTC)
    return (t - _EPOCH).total_seconds()


def _number_of_frames(ds) -> int:
    value = getattr(ds, "NumberOfFrames", None)
    if value in (None, ""):
        return 1
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"NumberOfFrames (0028,0008) must be an integer >= 1, got {value!r}") from None
    if n < 1:
        raise ValueError(f"NumberOfFrames (0028,0008) must be an integer >= 1, got {value!r}")
    return n


def _parse_dt(value, keyword: str, tag: str) -> _dt.datetime:
    from pydicom.valuerep import DT

    try:
        parsed = DT(str(value).strip())
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{keyword} {tag} must be a DICOM date-time (YYYYMMDDHHMMSS.FFFFFF&ZZXX), "
                         f"got {value!r}: {exc}") from None
    return _dt.datetime(parsed.year, parsed.month, parsed.day, parsed.hour, parsed.minute, parsed.second,
                        parsed.microsecond, tzinfo=parsed.tzinfo)


def _start_time(ds) -> _dt.datetime:
    """The first frame's time: AcquisitionDateTime, else AcquisitionDate + Time, else ContentDate + Time."""
    value = getattr(ds, "AcquisitionDateTime", None)
    if value not in (None, ""):
        return _parse_dt(value, "AcquisitionDateTime", "(0008,002A)")
    for date_kw, time_kw, tags in (("AcquisitionDate", "AcquisitionTime", "(0008,0022)/(0008,0032)"),
                                   ("ContentDate", "ContentTime", "(0008,0023)/(0008,0033)")):
        date, time = getattr(ds, date_kw, None), getattr(ds, time_kw, None)
        if date not in (None, "") and time not in (None, ""):
            return _parse_dt(f"{str(date).strip()}{str(time).strip()}", f"{date_kw}/{time_kw}", tags)
    raise ValueError("the object has no acquisition time: it lacks AcquisitionDateTime (0008,002A) (and "
                     "AcquisitionDate/AcquisitionTime, ContentDate/ContentTime), which pairing the planes needs")


def _cine_offsets_ms(ds, n: int) -> list[float]:
    """Each frame's offset (ms) from the first: FrameTimeVector where FrameIncrementPointer names it,
    else index x FrameTime."""
    pointer = getattr(ds, "FrameIncrementPointer", None)
    pointers: list[int] = []
    if pointer is not None:
        try:
            pointers = [int(p) for p in pointer]
        except TypeError:  # a single tag (an int), not a list of them
            pointers = [int(pointer)]
    vector = getattr(ds, "FrameTimeVector", None)
    if vector is not None and (0x00181065 in pointers or getattr(ds, "FrameTime", None) is None):
        try:
            increments = [float(v) for v in vector]
        except (TypeError, ValueError):
            raise ValueError(f"FrameTimeVector (0018,1065) must be numbers (ms), got {vector!r}") from None
        if len(increments) != n or not all(math.isfinite(v) and v >= 0 for v in increments) \
                or not all(v > 0 for v in increments[1:]):
            raise ValueError(f"FrameTimeVector (0018,1065) must hold {n} increments (ms), the first 0 and the "
                             f"others > 0, got {increments!r}")
        offsets, total = [], 0.0
        for v in increments:
            total += v
            offsets.append(total - increments[0])
        return offsets
    frame_time = getattr(ds, "FrameTime", None)
    needs_frame_time = (f"a cine of {n} frames needs FrameTime (0018,1063) in ms (or FrameTimeVector "
                        f"(0018,1065)) to time its frames, got {frame_time!r}")
    if frame_time is None:
        raise ValueError(needs_frame_time)
    try:
        ms = float(frame_time)
    except (TypeError, ValueError):
        raise ValueError(needs_frame_time) from None
    if not (math.isfinite(ms) and ms > 0):
        raise ValueError(f"FrameTime (0018,1063) must be a finite interval > 0 ms, got {frame_time!r}")
    return [i * ms for i in range(n)]


def _per_frame_times(ds, n: int) -> list[_dt.datetime] | None:
    """An enhanced object's FrameAcquisitionDateTime of every frame, or None where any is missing."""
    groups = getattr(ds, "PerFrameFunctionalGroupsSequence", None)
    if not groups or len(groups) != n:
        return None
    times = []
    for item in groups:
        content = getattr(item, "FrameContentSequence", None)
        value = getattr(content[0], "FrameAcquisitionDateTime", None) if content else None
        if value in (None, ""):
            return None
        times.append(_parse_dt(value, "FrameAcquisitionDateTime", "(0018,9074)"))
    return times
