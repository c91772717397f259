"""``histostudy listen``'s loop (§II-A): :func:`listen`, a :class:`.receiver.FrameReceiver` started,
served until Ctrl-C, a number of pose lines or a time-out, and its statistics returned; and the
short human line it can report per pose as it goes (:func:`pose_summary`).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable, Sequence

from histostudy.imaging import View
from histostudy.transducer import TransducerModel

from .access import check_listening_address
from .receiver import FrameReceiver, ReceiverConfig

__all__ = ["listen", "pose_summary"]

#: The most characters of a refusal's or an error's reason in a :func:`pose_summary` line.
_REASON_CHARS = 60


def pose_summary(record: dict, pairs_dropped: int, now: _dt.datetime | None = None) -> str:
    """One short line for a pose line ``record`` (:func:`.pose_lines.pose_line`): the wall-clock
    time ``now`` (default: now), the pair's index, how it was found (``warm``, ``from_scratch``,
    ``reacquired``; ``error`` when its pose or pixels raised), ``accepted`` or ``REFUSED`` with the
    verdict's first reason (shortened), the focal point (mm, C-arm frame), the latency (ms, from the
    pair's last frame received to its line written) and ``pairs_dropped`` so far.

    ``HH:MM:SS.fff pair <index> <kind> accepted|REFUSED (<reason>) focal (<x>, <y>, <z>) mm latency <ms>
    ms dropped <n>``
    """
    now = _dt.datetime.now() if now is None else now
    if "error" in record:
        kind, verdict, focal = "error", "ERROR " + _short(record["error"]), "-"
    else:
        reasons = record.get("verdict", {}).get("reasons") or []
        kind = record.get("tracking") or "-"
        verdict = "accepted" if record.get("accepted") else "REFUSED" + (f" ({_short(reasons[0])})" if reasons else "")
        focal = "(" + ", ".join(f"{float(v):.2f}" for v in record["focal_point_mm"]) + ") mm"
    latency_ms = 1000.0 * float(record["seconds"]["latency"])
    return (f"{now.strftime('%H:%M:%S.%f')[:-3]} pair {record['pair_index']} {kind} {verdict} focal {focal} "
            f"latency {latency_ms:.0f} ms dropped {int(pairs_dropped)}")


def _short(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= _REASON_CHARS else text[:_REASON_CHARS - 3] + "..."


def listen(views: Sequence[View], config: ReceiverConfig | None = None, *, max_pairs: int | None = None,
           timeout_s: float | None = None, model: TransducerModel | None = None, seed=0,
           on_pose: Callable[[dict], object] | None = None, on_start: Callable[[int], object] | None = None,
           on_summary: Callable[[str], object] | None = None, **tracker_options) -> dict:
    """Receive live C-arm frames and write a pose per biplane pair until Ctrl-C, ``max_pairs`` lines
    or ``timeout_s`` seconds (what ``histostudy listen`` runs).

    The address is tried first (:func:`.access.check_listening_address`): one in use raises an
    OSError naming the host and port at once, before the models load and before the output is created.

    Args:
        views: one view per plane, as :class:`.receiver.FrameReceiver`'s.
        config: the receiver's settings (:class:`.receiver.ReceiverConfig`: address, output, who may
            send, ``max_queued_pairs`` ...); None: its defaults.
        max_pairs: stop once this many pairs have their line; None: no limit.
        timeout_s: stop after this many seconds (s); None: no limit.
        model, seed, on_pose: as :class:`.receiver.FrameReceiver`'s.
        **tracker_options: as :class:`.receiver.FrameReceiver`'s.
        on_start: called once listening, with the bound port (useful with port 0).
        on_summary: called after each pose line, after ``on_pose``, with its :func:`pose_summary`
            (the pairs dropped so far: the stats' ``pairs_skipped``).

    Returns:
        :meth:`.receiver.FrameReceiver.stats` at the end.

    Raises:
        TypeError: ``on_summary`` not callable (or ``on_pose``, without ``on_summary``).
        ValueError: ``max_pairs`` not None or an integer >= 1, ``timeout_s`` not None or a finite
            number > 0, or views the receiver refuses.
        OSError: the address cannot be bound.
    """
    if on_summary is not None and not callable(on_summary):
        raise TypeError(f"on_summary must be callable (text -> None) or None, got {type(on_summary).__name__}")
    config = ReceiverConfig() if config is None else config
    check_listening_address(config.host, config.port)
    receiver: FrameReceiver | None = None

    def posed(record: dict) -> None:
        try:
            if on_pose is not None:
                on_pose(record)
        finally:  # the summary line even when the caller's on_pose fails (the receiver logs that)
            # given as on_pose only with on_summary, and called by the receiver's worker once it started
            assert on_summary is not None and receiver is not None
            on_summary(pose_summary(record, receiver.stats()["pairs_skipped"]))

    receiver = FrameReceiver(views, config, model=model, seed=seed,
                             on_pose=posed if on_summary is not None else on_pose, **tracker_options)
    bound = receiver.start()
    if on_start is not None:
        try:
            on_start(bound)
        except BaseException:
            receiver.stop(drain=False)
            raise
    try:
        return receiver.serve_forever(max_pairs=max_pairs, timeout_s=timeout_s)
    finally:
        # serve_forever stops the receiver once it serves; a bad max_pairs or timeout_s raises before
        # that, and the receiver started above must not be left listening with its worker running
        receiver.stop(drain=False)
