"""The moving cine (:mod:`histostudy.study.your_data.moving_cine`) streamed at its frame rate through
the pose receiver on loopback, and what came out: a row per frame (posed, dropped, refused; focal
error against the truth, mm; latency, s), the counts and the figure (docs/tracking.md).
"""

from __future__ import annotations

import datetime as _dt
import json
import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.imaging import load_views
from histostudy.lab import FrameReceiver, ReceiverConfig, stream_frames
from histostudy.transducer import TransducerModel

from .moving_cine import MovingCine

__all__ = ["MovingCineRun", "count_table", "frame_table", "plot_focal_error", "stream_moving_cine"]


@dataclass(frozen=True)
class MovingCineRun:
    """One stream of a moving cine through the receiver (:func:`stream_moving_cine`).

    Args:
        records: the pose records, as the receiver wrote them.
        stats: the receiver's :meth:`histostudy.lab.FrameReceiver.stats` once stopped.
        sent: what the sender sent, a :class:`histostudy.lab.SentObject` per object in the cine's order.
        stream_s: from the first object sent to the last answered, s.
        wall_s: from the first object sent to the last pose, s.
        max_queued_pairs: the receiver's bound on waiting pairs (None: none).
    """

    records: list
    stats: dict
    sent: list
    stream_s: float
    wall_s: float
    max_queued_pairs: int | None


def stream_moving_cine(cine: MovingCine, model: TransducerModel, seed: int, *, output_path: str | os.PathLike,
                       fast=True, max_queued_pairs: int | None = 2, pace: float = 1.0,
                       on_pose: Callable[[dict], object] | None = None, sender_process: bool = False,
                       **receiver_options) -> MovingCineRun:
    """Stream ``cine`` at its frame rate (times ``pace``) to a pose receiver on loopback.

    Args:
        model: the digital model of eq. 3 the receiver's tracker fits.
        seed: the tracker's draws.
        output_path: the receiver's JSON-lines file (replaced if it exists).
        fast: the tracker's warm path (``FrameReceiver``'s ``fast``).
        max_queued_pairs: the most pairs waiting for a pose; beyond, the oldest is dropped (None:
            none dropped, the receiver falls behind a stream faster than its poses).
        pace: the speed-up of the sending (1.0: the frames' own times).
        on_pose: called with each record on the receiver's worker thread (a sleeping one slows
            the tracker down).
        sender_process: send from a process of its own, as a C-arm sends from a machine of its
            own (it still shares this machine's cores); False: from this process's thread, where
            the sender's Python holds the interpreter lock the receiver and the tracker also need.
        receiver_options: more :class:`~histostudy.lab.FrameReceiver` arguments.

    After the last object is sent the receiver stops and poses what waits (at most
    ``max_queued_pairs``).

    Returns:
        The :class:`MovingCineRun`.

    Raises:
        ConnectionError: as the sender does.
    """
    output = Path(output_path)
    output.unlink(missing_ok=True)  # the receiver appends: start from an empty file
    config, tracker_options = ReceiverConfig.split(receiver_options, output_path=output, port=0, host="127.0.0.1",
                                                   fast=fast, max_queued_pairs=max_queued_pairs,
                                                   default_interval_s=1.0 / cine.fps)
    receiver = FrameReceiver(load_views(cine.views), config, model=model, seed=seed, on_pose=on_pose, **tracker_options)
    receiver.start()
    t0 = time.perf_counter()
    paths = [p for pair in cine.frames for p in pair]
    try:
        if sender_process:
            # spawn, not fork: the receiver's threads and torch's pools are running in this process
            with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
                sent = pool.submit(stream_frames, paths, "127.0.0.1", receiver.port, ae_title=receiver.ae_title,
                                   pace=pace).result()
        else:
            sent = stream_frames(paths, "127.0.0.1", receiver.port, ae_title=receiver.ae_title, pace=pace)
    finally:
        receiver.stop(drain=True)
    wall_s = time.perf_counter() - t0
    records = [json.loads(line) for line in output.read_text(encoding="utf-8").splitlines() if line.strip()]
    return MovingCineRun(records=records, stats=receiver.stats(), sent=sent,
                         stream_s=sent[-1].answered_s - sent[0].sent_s if sent else 0.0, wall_s=wall_s,
                         max_queued_pairs=max_queued_pairs)


def frame_table(run: MovingCineRun, cine: MovingCine) -> pd.DataFrame:
    """One row per frame of ``cine``: ``frame``, ``time_s``, the truth's ``speed_mm_s``, ``status``
    (``"posed"``: a pose line; ``"refused"``: an object of the pair refused by the receiver;
    ``"dropped"``: sent and answered but never posed — skipped by ``max_queued_pairs``, or left
    unpaired), ``tracking`` (``from_scratch``, ``warm``, ``reacquired``), ``accepted`` (the verdict),
    ``focal_error_mm`` (``|T_est t - T_true t|`` of the posed frames, NaN otherwise), ``latency_s``
    (the pair's last frame received to its line), ``queue_s``, ``pose_s`` and ``pair_index``.

    Args:
        run: the stream (:func:`stream_moving_cine`).
        cine: the cine streamed (its truth is read).

    Returns:
        The table.

    Raises:
        ValueError: a record whose frame time lies outside the cine.
    """
    truth = cine.read_truth()
    n = cine.n_frames
    planes = len(cine.frames[0]) if n else 0
    rows = [{"frame": k, "time_s": float(cine.times_s[k]), "speed_mm_s": float(truth["speed_mm_s"][k]),
             "status": "dropped", "tracking": None, "accepted": False, "focal_error_mm": np.nan,
             "latency_s": np.nan, "queue_s": np.nan, "pose_s": np.nan, "pair_index": -1} for k in range(n)]
    for sent in run.sent:
        if sent.status != 0:
            rows[sent.index // planes]["status"] = "refused"
    for record in run.records:
        k = cine.frame_at(_dt.datetime.fromisoformat(record["frame_times"][0]))
        if not 0 <= k < n:
            raise ValueError(f"record of pair {record['pair_index']} has frame time {record['frame_times'][0]}, "
                             f"outside the cine's {n} frames")
        row = rows[k]
        row.update(status="posed", tracking=record.get("tracking"), accepted=bool(record.get("accepted")),
                   pair_index=int(record["pair_index"]), latency_s=record["seconds"]["latency"],
                   queue_s=record["seconds"]["queue"], pose_s=record["seconds"]["pose"])
        if record.get("T_carm_transducer") is not None:
            estimate = np.asarray(record["T_carm_transducer"], dtype=float)
            row["focal_error_mm"] = float(np.linalg.norm(estimate[:3, 3] - truth["T_carm_transducer"][k][:3, 3]))
    return pd.DataFrame(rows)


def count_table(run: MovingCineRun, frames: pd.DataFrame) -> pd.DataFrame:
    """The run in numbers (``quantity``, ``value``): pairs sent, posed, dropped by the receiver
    (``max_queued_pairs``), refused (an object of the pair refused), whether they add up, and the
    frames left unpaired (0 unless an object was refused); the tracking (warm, from scratch, warm
    starts tried again at the rescue scale and held by that second attempt, warm starts from a
    refused pose and held, lost, re-acquired, accepted); the rates (frames of the cine per second,
    poses per second over the stream); the latency (median, 90th percentile, largest) and the focal error of
    the accepted poses (mean, median, 95th percentile, largest); how late the sender ran. The rates
    are over ``run.stream_s`` (the C-arm's time) and ``run.wall_s`` (the last poses come after it).

    Args:
        run: the stream.
        frames: :func:`frame_table` of it.

    Returns:
        Rows ``quantity``, ``value``.
    """
    s, tracker = run.stats, run.stats.get("tracker", {})
    n_sent = len(frames)
    refused = int((frames["status"] == "refused").sum())
    posed = frames["status"] == "posed"
    accepted = frames.loc[posed & frames["accepted"], "focal_error_mm"].to_numpy(float)
    latency = frames.loc[posed, "latency_s"].to_numpy(float)
    late = np.array([o.late_s for o in run.sent]) if run.sent else np.zeros(1)

    def pct(values, q):
        return float(np.percentile(values, q)) if len(values) else np.nan

    rows = [("pairs sent", n_sent), ("pairs posed", int(s["pairs_processed"])),
            ("pairs dropped by the receiver (max_queued_pairs)", int(s["pairs_skipped"])),
            ("pairs refused (an object refused)", refused), ("frames left unpaired", int(s["frames_unpaired"])),
            ("sent = posed + dropped + refused", n_sent == s["pairs_processed"] + s["pairs_skipped"] + refused),
            ("max_queued_pairs", run.max_queued_pairs), ("most pairs ever waiting", int(s["pairs_waiting_max"])),
            ("warm updates", tracker.get("n_warm")), ("estimates from scratch", tracker.get("n_from_scratch")),
            ("warm starts tried again (rescue_scale)", tracker.get("n_rescue_attempts")),
            ("warm starts held by the second attempt", tracker.get("n_rescued")),
            ("warm starts from a refused pose (resume_refused)", tracker.get("n_resume_attempts")),
            ("warm starts from a refused pose held", tracker.get("n_resumed")),
            ("track lost", tracker.get("n_lost")), ("track re-acquired", tracker.get("n_reacquired")),
            ("poses accepted", int(s["pairs_accepted"])),
            ("cine frames per second", n_sent / run.stream_s if run.stream_s > 0 else np.nan),
            ("poses per second (over the stream)", s["pairs_processed"] / run.stream_s if run.stream_s > 0 else np.nan),
            ("poses per second (first frame sent to last pose)",
             s["pairs_processed"] / run.wall_s if run.wall_s > 0 else np.nan),
            ("fraction of pairs posed", s["pairs_processed"] / n_sent if n_sent else np.nan),
            ("latency median (s)", pct(latency, 50)), ("latency 90th percentile (s)", pct(latency, 90)),
            ("latency largest (s)", float(latency.max()) if len(latency) else np.nan),
            ("pose work per pair, median (s)", pct(frames.loc[posed, "pose_s"].to_numpy(float), 50)),
            ("focal error mean (mm, accepted)", float(accepted.mean()) if len(accepted) else np.nan),
            ("focal error median (mm, accepted)", pct(accepted, 50)),
            ("focal error 95th percentile (mm, accepted)", pct(accepted, 95)),
            ("focal error largest (mm, accepted)", float(accepted.max()) if len(accepted) else np.nan),
            ("sender behind the C-arm, largest (s)", float(max(0.0, late.max())))]
    return pd.DataFrame(rows, columns=["quantity", "value"])


def plot_focal_error(frames: pd.DataFrame, *, title: str = "Focal error per frame, streamed at the frame rate"):
    """Focal error per posed frame against the time (top; the verdict's refusals as crosses,
    re-acquisitions ringed, the dropped frames as ticks along the bottom, the robot's speed in
    grey on the right axis) and the latency of each pose (bottom).

    Args:
        frames: :func:`frame_table`'s table.
        title: the top panel's title.

    Returns:
        A matplotlib Figure (not managed by pyplot).

    Raises:
        ValueError: ``frames`` lacks a column.
    """
    from matplotlib.figure import Figure

    needed = {"time_s", "status", "tracking", "accepted", "focal_error_mm", "latency_s", "speed_mm_s"}
    if not needed <= set(frames.columns):
        raise ValueError(f"frames must be frame_table's table with columns {sorted(needed)}, "
                         f"got {sorted(frames.columns)}")
    fig = Figure(figsize=(8.0, 5.0))
    ax, ax_lat = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    speed = ax.twinx()
    speed.plot(frames["time_s"], frames["speed_mm_s"], color="0.75", lw=1, zorder=0)
    speed.set_ylabel("robot speed (mm/s)", color="0.5")
    ax.set_zorder(speed.get_zorder() + 1)
    ax.patch.set_visible(False)
    posed = frames[frames["status"] == "posed"]
    ok = posed[posed["accepted"]]
    ax.plot(ok["time_s"], ok["focal_error_mm"], ".", color="tab:blue", ms=4, label="posed (accepted)")
    bad = posed[~posed["accepted"]]
    ax.plot(bad["time_s"], bad["focal_error_mm"], "x", color="tab:red", ms=6, label="refused by the verdict")
    again = posed[posed["tracking"].isin(["reacquired", "from_scratch"])]
    ax.plot(again["time_s"], again["focal_error_mm"], "o", mfc="none", mec="tab:orange", ms=9,
            label="from scratch / re-acquired")
    top = np.nanmax(posed["focal_error_mm"].to_numpy(float)) if len(posed) and posed["focal_error_mm"].notna().any() \
        else 1.0
    dropped = frames[frames["status"] != "posed"]
    ax.plot(dropped["time_s"], np.zeros(len(dropped)), "|", color="0.3", ms=8,
            label=f"dropped or refused ({len(dropped)})")
    ax.set_ylim(-0.05 * top, 1.1 * top)
    ax.set_ylabel("focal error (mm)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax_lat.plot(posed["time_s"], posed["latency_s"], ".", color="tab:purple", ms=4)
    ax_lat.set_ylabel("latency (s)")
    ax_lat.set_xlabel("time in the cine (s)")
    fig.tight_layout()
    return fig
