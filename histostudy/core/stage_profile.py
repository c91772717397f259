"""Where a run's time goes, by stage of the study: :func:`stage` charges a block's wall and CPU time to
one of :data:`STAGES`, exclusively (a stage opened inside another pauses it), and the totals of worker
processes are added to their caller's (docs/report.md, "Where the time goes").
"""

from __future__ import annotations

import contextlib
import os
import resource
import threading
import time
from collections.abc import Mapping

__all__ = ["STAGES", "cpu_seconds", "merge_stage_totals", "stage", "stage_delta", "stage_totals"]

#: The stages a run's time is charged to, in the order the report lists them.
STAGES = ("render", "segment", "orient", "pose", "calibrate", "statistics", "report")

#: The clocks a stage reads (seconds): wall time, and the CPU time of this process (all its threads,
#: ``time.process_time``). Module attributes, so that a test can replace them with a clock it steps.
wall_clock = time.perf_counter
cpu_clock = time.process_time



def cpu_seconds(*, own: bool = True, children: bool = True) -> float:
    """User + system CPU seconds of this process and of its children that have finished and been
    waited for (rendering workers, notebook kernels), as a run's CPU-hours count them.

    Args:
        own: count this process (all its threads).
        children: count its reaped children.

    Returns:
        The seconds since each process started; a difference of two readings is a block's.
    """
    total = 0.0
    for who, wanted in ((resource.RUSAGE_SELF, own), (resource.RUSAGE_CHILDREN, children)):
        if wanted:
            usage = resource.getrusage(who)
            total += usage.ru_utime + usage.ru_stime
    return total


_FIELDS = ("wall_s", "cpu_s", "calls")
_LOCK = threading.Lock()
#: name -> [wall_s, cpu_s, calls] of this process (and what was merged into it)
_TOTALS: dict[str, list] = {}
#: per thread: ``stack``, the open stages as [name, depth], innermost last; ``since``, the (wall,
#: cpu) readings at which the innermost one last started or resumed
_THREAD = threading.local()


class _Stage(contextlib.ContextDecorator):
    """The context manager (and decorator) :func:`stage` returns; it keeps no state of its own (the
    open stages are the thread's), so one instance serves every thread and nested entry."""

    __slots__ = ("name",)

    def __init__(self, name: str):
        self.name = name

    def __enter__(self):
        _enter(self.name)
        return self

    def __exit__(self, *exc):
        _exit(self.name)
        return False


_INSTANCES = {name: _Stage(name) for name in STAGES}


def stage(name: str) -> _Stage:
    """Charge the time of a block (``with stage("render"):``) or of every call of a function
    (``@stage("render")``) to the stage ``name``.

    The charge is exclusive: a stage opened inside another pauses the outer one until it closes, so
    a render inside a pose estimate is charged to ``render``, not to ``pose``. The same stage opened
    inside itself is one call and its time is counted once. The open stages are the calling
    thread's; each thread charges its own blocks. The CPU time is the process's
    (``time.process_time``: all its threads), read as the block opens and closes: the work of the
    thread pools a block starts (numba, torch, BLAS) counts in its stage, and so does the work of
    any other thread that runs meanwhile, so where two threads are inside stages at once each
    is charged the process's CPU time of the overlap.

    Args:
        name: one of :data:`STAGES`.

    Returns:
        A context manager that is also a decorator (one instance per stage, safe across threads).

    Raises:
        ValueError: ``name`` is not one of :data:`STAGES`.
    """
    try:
        return _INSTANCES[name]
    except (KeyError, TypeError):
        raise ValueError(f"name must be one of {STAGES}, got {name!r}") from None


def _thread_state() -> list:
    stack = getattr(_THREAD, "stack", None)
    if stack is None:
        stack = _THREAD.stack = []
    return stack


def _charge(name: str, wall_s: float, cpu_s: float, calls: int = 0) -> None:
    """Add to ``name``'s totals; the caller holds the lock."""
    entry = _TOTALS.get(name)
    if entry is None:
        entry = _TOTALS[name] = [0.0, 0.0, 0]
    entry[0] += wall_s
    entry[1] += cpu_s
    entry[2] += calls


def _enter(name: str) -> None:
    stack = _thread_state()
    if stack and stack[-1][0] == name:
        stack[-1][1] += 1  # the same stage inside itself: no clock read, no new call
        return
    now = (wall_clock(), cpu_clock())
    new_call = all(entry[0] != name for entry in stack)
    with _LOCK:
        if stack:  # the outer stage pauses: its time so far is charged now
            since = _THREAD.since
            _charge(stack[-1][0], now[0] - since[0], now[1] - since[1])
        if new_call:
            _charge(name, 0.0, 0.0, 1)
    stack.append([name, 1])
    _THREAD.since = now


def _exit(name: str) -> None:
    stack = _thread_state()
    top = stack[-1] if stack else None
    if top is not None and top[0] == name and top[1] > 1:
        top[1] -= 1
        return
    # the innermost open entry of ``name``: the top, unless blocks closed out of order (a generator
    # suspended inside a stage); the innermost stage is charged the time since it started
    index = next((i for i in range(len(stack) - 1, -1, -1) if stack[i][0] == name), None)
    if index is None:
        return
    now = (wall_clock(), cpu_clock())
    since = _THREAD.since
    with _LOCK:
        _charge(stack[-1][0], now[0] - since[0], now[1] - since[1])
    if stack[index][1] > 1:
        stack[index][1] -= 1
    else:
        del stack[index]
    _THREAD.since = now


def stage_totals() -> dict:
    """This process's stage totals so far, merged ones included (a copy).

    Returns:
        ``{name: {"wall_s", "cpu_s", "calls"}}`` for each stage charged so far (s, s, count); a
        stage still open counts its call but not yet its time.
    """
    with _LOCK:
        return {name: dict(zip(_FIELDS, (float(e[0]), float(e[1]), int(e[2])))) for name, e in _TOTALS.items()}


def stage_delta(before: Mapping, after: Mapping | None = None) -> dict:
    """What was charged between two snapshots of :func:`stage_totals`.

    Args:
        before: the earlier snapshot.
        after: the later snapshot; None: the totals now.

    Returns:
        ``{name: {"wall_s", "cpu_s", "calls"}}`` of ``after - before``, the stages without a change
        left out, in the order of :data:`STAGES`.

    Raises:
        ValueError: a snapshot names a stage outside :data:`STAGES` or lacks a field.
    """
    after = stage_totals() if after is None else after
    old, new = _checked(before, "before"), _checked(after, "after")
    delta = {}
    for name in STAGES:
        if name in new:
            change = {k: new[name][k] - old.get(name, {}).get(k, 0) for k in _FIELDS}
            if any(change.values()):
                delta[name] = change
    return delta


def merge_stage_totals(delta: Mapping) -> None:
    """Add the stage totals of work done elsewhere (a worker process's :func:`stage_delta`) to this
    process's, so that its snapshots include them. Wall times add up as CPU times do: a stage's wall
    time is then the sum over the processes that ran it.

    Args:
        delta: ``{name: {"wall_s", "cpu_s", "calls"}}``, names from :data:`STAGES`.

    Raises:
        ValueError: ``delta`` names a stage outside :data:`STAGES` or lacks a field.
    """
    checked = _checked(delta, "delta")
    with _LOCK:
        for name, entry in checked.items():
            _charge(name, entry["wall_s"], entry["cpu_s"], entry["calls"])


def _checked(totals, name: str) -> dict:
    if not isinstance(totals, Mapping):
        raise ValueError(f"{name} must be a mapping of stage names to totals, got {type(totals).__name__}")
    out = {}
    for stage_name, entry in totals.items():
        if stage_name not in STAGES:
            raise ValueError(f"{name} names the stage {stage_name!r}; the stages are {STAGES}")
        if not isinstance(entry, Mapping) or any(k not in entry for k in _FIELDS):
            raise ValueError(f"{name}[{stage_name!r}] must hold {_FIELDS}, got {entry!r}")
        out[stage_name] = {"wall_s": float(entry["wall_s"]), "cpu_s": float(entry["cpu_s"]),
                           "calls": int(entry["calls"])}
    return out


def _after_fork() -> None:
    # a fork copies the lock in whatever state another thread held it
    global _LOCK
    _LOCK = threading.Lock()


os.register_at_fork(after_in_child=_after_fork)
