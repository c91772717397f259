"""What the live receiver counts and times (§II-A): objects, frames, pairs, rejections, seconds per
stage and the latency's percentiles, kept under the receiver's lock (:class:`ReceiverCounts`).
"""

from __future__ import annotations

import collections

import numpy as np

from histostudy.core import to_jsonable

__all__ = ["COUNT_KEYS", "LATENCY_WINDOW", "ReceiverCounts"]

#: The counters :meth:`ReceiverCounts.stats` reports (0 until counted).
COUNT_KEYS = ("objects_received", "objects_accepted", "objects_duplicate", "objects_rejected", "frames_received",
              "frames_unpaired", "pairs_completed", "pairs_processed", "pairs_accepted", "pairs_errors",
              "pairs_skipped", "pairs_dropped_stale", "pairs_waiting_max", "connections", "connections_silent",
              "associations", "associations_aborted", "associations_rejected", "tls_refused")

#: How many of the last lines' latencies the percentiles of :meth:`ReceiverCounts.stats` are taken over.
LATENCY_WINDOW = 10_000


class ReceiverCounts:
    """The receiver's counters and timers; not thread-safe by itself (the receiver holds its lock).

    Attributes:
        counts: a ``collections.Counter`` of :data:`COUNT_KEYS` (and any other event).
        rejections: rejected objects per status (``"0xA900"``, ...).
        last_rejections: the last 20 rejections (instance UID, SOP class, status, reason).
        last_association_rejections: the last 20 associations rejected at negotiation (peer,
            calling and called AE titles, A-ASSOCIATE-RJ reason, why).
        decode_s, pose_s, latency_s: seconds summed: decoding (the headers in the handlers, the
            pixels of the pairs taken by the pose worker), the pose worker's work per line, and
            from each pair's last frame received to its line.
        latencies_s: the latency of each of the last :data:`LATENCY_WINDOW` lines (s), oldest first.
        t_first_frame, t_last_line, t_started: ``perf_counter`` times of the first frame decoded,
            the last line written and the server's start (None until then).
        warm_up_s: seconds of the tracker's warm-up at the start (None without one).
        tracker: the last snapshot of :meth:`histostudy.pose.Tracker.stats`.
    """

    def __init__(self, tracker_stats: dict):
        self.counts: collections.Counter[str] = collections.Counter()
        self.rejections: collections.Counter[str] = collections.Counter()
        self.last_rejections: collections.deque[dict] = collections.deque(maxlen=20)
        self.last_association_rejections: collections.deque[dict] = collections.deque(maxlen=20)
        self.decode_s = self.pose_s = self.latency_s = 0.0
        self.latencies_s: collections.deque[float] = collections.deque(maxlen=LATENCY_WINDOW)
        self.t_first_frame: float | None = None
        self.t_last_line: float | None = None
        self.t_started: float | None = None
        self.warm_up_s: float | None = None
        self.tracker = tracker_stats

    def add_rejection(self, status: int, uid: str, sop_class: str, reason: str) -> None:
        """One object refused with C-STORE ``status`` (an int) for ``reason``."""
        self.counts["objects_rejected"] += 1
        self.rejections[f"0x{status:04X}"] += 1
        self.last_rejections.append({"instance_uid": uid, "sop_class_uid": sop_class, "status": status,
                                     "reason": reason})

    def add_association_rejection(self, record: dict) -> None:
        """One association rejected at negotiation (:class:`.access.AssociationGate`'s ``record``)."""
        self.counts["associations_rejected"] += 1
        self.last_association_rejections.append(dict(record))

    def add_line(self, record: dict, tracker_stats: dict, now: float) -> None:
        """One pose line written at ``now``: its outcome and seconds, and the tracker's counters then."""
        self.counts["pairs_processed"] += 1
        self.counts["pairs_accepted"] += bool(record.get("accepted"))
        self.counts["pairs_errors"] += "error" in record
        self.pose_s += record["seconds"]["pose"]
        self.latency_s += record["seconds"]["latency"]
        self.latencies_s.append(record["seconds"]["latency"])
        self.t_last_line = now
        self.tracker = tracker_stats

    def stats(self, *, n_views: int, pairs_waiting: int, port: int, now: float) -> dict:
        """The JSON-ready statistics of :meth:`.receiver.FrameReceiver.stats` at ``now``.

        ``objects_received`` / ``objects_accepted`` / ``objects_rejected`` (with ``rejections`` per
        status and ``last_rejections``' reasons), ``frames_received``, ``frames_unpaired``,
        ``pairs_completed`` (paired), ``pairs_processed`` (a line written), ``pairs_accepted``,
        ``pairs_errors`` (the pose or the pixels raised), ``pairs_skipped`` (every pair without a line:
        dropped for a newer one, or left waiting when the receiver stopped), ``pairs_dropped_stale``
        (those dropped for a newer one, ``max_queued_pairs``), ``pairs_waiting`` (now) and
        ``pairs_waiting_max`` (the most that ever waited: at most ``max_queued_pairs``);
        ``latency_s``: ``p50``, ``p90``, ``p99`` and ``max`` of the latency (s, from a pair's last
        frame received to its line written; ``numpy.percentile``, linear) over the last
        :data:`LATENCY_WINDOW` lines, ``n`` of them, and ``mean`` over every line (None without a
        line); ``connections``, ``connections_silent`` (closed for sending nothing within
        ``first_bytes_wait_s``), ``associations``,
        ``associations_aborted``, ``associations_rejected`` on the first bytes or at negotiation (with
        ``last_association_rejections``: peer, AE titles, reason) and ``tls_refused`` (TLS
        handshakes failed: no certificate, or one the CA did not sign); ``stage_seconds``
        summed (``decode`` in the handlers, the pose stages of :meth:`histostudy.pose.Tracker.stats`)
        and ``seconds_per_pair`` (those over ``pairs_processed``, plus ``pose`` and ``latency``);
        ``frames_per_s``: the frames of the processed pairs over the time from the first frame received
        to the last line written; ``pose_frames_per_s``: the same frames over the pose worker's busy
        time; ``tracker``: the tracker's counters (:meth:`histostudy.pose.Tracker.stats`) at the last line; ``port``;
        ``elapsed_s`` since the server started; ``warm_up_s``: the tracker's warm-up at the start
        (None without one).
        """
        n_pairs = self.counts.get("pairs_processed", 0)
        n_frames = n_pairs * n_views
        stage = {"decode": self.decode_s, **self.tracker["stage_seconds"]}
        span = None if self.t_first_frame is None or self.t_last_line is None else \
            self.t_last_line - self.t_first_frame
        out: dict[str, object] = {key: self.counts.get(key, 0) for key in COUNT_KEYS}
        out.update({
            "pairs_waiting": pairs_waiting,
            "rejections": dict(self.rejections),
            "last_rejections": list(self.last_rejections),
            "last_association_rejections": list(self.last_association_rejections),
            "stage_seconds": stage,
            "seconds_per_pair": ({k: v / n_pairs for k, v in stage.items()}
                                 | {"pose": self.pose_s / n_pairs, "latency": self.latency_s / n_pairs})
            if n_pairs else {},
            "latency_s": self._latency_summary(n_pairs),
            "frames_per_s": n_frames / span if span else None,
            "pose_frames_per_s": n_frames / self.pose_s if self.pose_s > 0 else None,
            "tracker": self.tracker,
            "port": port,
            "elapsed_s": None if self.t_started is None else now - self.t_started,
            "warm_up_s": self.warm_up_s,
        })
        return to_jsonable(out)

    def _latency_summary(self, n_pairs: int) -> dict:
        """The latency's percentiles over :attr:`latencies_s` and its mean over every line (s)."""
        if not self.latencies_s:
            return {"p50": None, "p90": None, "p99": None, "max": None, "mean": None, "n": 0}
        p50, p90, p99 = np.percentile(np.asarray(self.latencies_s), [50, 90, 99])
        return {"p50": float(p50), "p90": float(p90), "p99": float(p99), "max": float(max(self.latencies_s)),
                "mean": self.latency_s / n_pairs, "n": len(self.latencies_s)}
