"""Notebook 06's live section: the lab's cine streamed over DICOM to the pose receiver on loopback, as
a C-arm streams it during tracking (§II-A), its poses set beside the tracked ones, and the receiver's
throughput. Lengths in mm, the C-arm frame; times in seconds.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.lab import FrameReceiver, ReceiverConfig, send_frames
from histostudy.pose import frames_from_files
from histostudy.transducer import TransducerModel

from ..section import SectionPart, Timer
from ._inputs import LabInputs, cine_frame_count
from ._section import YourDataSetup

_AXES = "xyz"


def stream_cine(inputs: LabInputs, model: TransducerModel, seed: int, *, output_path: str | os.PathLike,
                max_pairs: int | None = None, on_pose: Callable[[dict], object] | None = None,
                timeout_s: float = 600.0) -> tuple[list[dict], dict]:
    """Stream the cine of ``inputs`` to a pose receiver on loopback and collect a pose per pair.

    The receiver listens on ``127.0.0.1`` (a free port) with the cine's views (the views file's, or
    the DICOM geometry tags' named as the files) and ``model``, its tracker seeded with ``seed`` and
    on the full frames as :func:`track_cine`'s (``fast=False``), so that the same frames
    give the same poses; the cine files go to it in one association
    (:func:`histostudy.lab.send_frames`).

    Args:
        output_path: the receiver's JSON-lines file (replaced if it exists).
        max_pairs: the pairs to pose (the first ones; None: every frame of the cine).
        on_pose: called with each pair's record as it is written (on the receiver's worker thread).
        timeout_s: the longest wait for the poses, seconds.

    Returns:
        The records (one dict per pair, as :mod:`histostudy.lab.receiver` writes them) and the
        receiver's :meth:`~histostudy.lab.FrameReceiver.stats`.

    Raises:
        RuntimeError: the receiver refused an object (its reasons).
        TimeoutError: fewer than the expected pairs were posed within ``timeout_s``.
    """
    n = cine_frame_count(inputs)
    if max_pairs is not None:
        if isinstance(max_pairs, bool) or not isinstance(max_pairs, (int, np.integer)) or max_pairs < 1:
            raise ValueError(f"max_pairs must be None or an integer >= 1, got {max_pairs!r}")
        n = min(n, int(max_pairs))
    output = Path(output_path)
    output.unlink(missing_ok=True)  # the receiver appends: start from an empty file
    views = [f.view for f in frames_from_files(inputs.cine, inputs.views, frame_index=0)]
    receiver = FrameReceiver(views, ReceiverConfig(output_path=output, port=0, host="127.0.0.1",
                                                   fast=False,  # track_cine's full-frame path: the same poses
                                                   max_queued_pairs=None),  # a cine sent at once: every pair posed
                             model=model, seed=seed, on_pose=on_pose)
    receiver.start()
    try:
        statuses = send_frames(inputs.cine, "127.0.0.1", receiver.port, ae_title=receiver.ae_title)
    except BaseException:
        receiver.stop(drain=False)
        raise
    if any(statuses):
        receiver.stop(drain=False)
        reasons = [r["reason"] for r in receiver.stats()["last_rejections"]]
        raise RuntimeError(f"the receiver refused cine objects (statuses {[f'0x{s:04X}' for s in statuses]}): "
                           f"{reasons}")
    stats = receiver.serve_forever(max_pairs=n, timeout_s=timeout_s)
    records = [json.loads(line) for line in output.read_text(encoding="utf-8").splitlines() if line.strip()]
    if len(records) < n:
        raise TimeoutError(f"the receiver posed {len(records)} of the cine's {n} pairs within timeout_s={timeout_s} s")
    return records, stats


class LiveFocalFigure:
    """A figure of the focal point (x, y, z in mm, C-arm frame) per received pair, redrawn as each
    pose arrives: pass the object as ``on_pose``. Refused poses are circled.

    Args:
        n_pairs: the pairs expected (the x axis' extent).
        reference: a table with ``frame`` and ``focal_{x,y,z}_mm`` (:func:`track_cine`'s)
            drawn as grey crosses, where the received points should land; None: none.
        show: display the figure through an ``IPython.display`` handle and update it with each
            pose (a live figure in JupyterLab and in papermill's output); outside IPython nothing
            is shown.

    ``figure`` is the matplotlib :class:`~matplotlib.figure.Figure` (not managed by pyplot, so a
    notebook shows it once, through its handle); ``records`` the records drawn.
    """

    def __init__(self, n_pairs: int, *, reference: pd.DataFrame | None = None, show: bool = True,
                 title: str = "Focal point per received pair (live)"):
        from matplotlib.figure import Figure
        from matplotlib.ticker import MaxNLocator

        if isinstance(n_pairs, bool) or not isinstance(n_pairs, (int, np.integer)) or n_pairs < 1:
            raise ValueError(f"n_pairs must be an integer >= 1, got {n_pairs!r}")
        self.records: list[dict] = []
        self._lock = threading.Lock()
        self.figure = Figure(figsize=(7.0, 3.4))
        ax = self.ax = self.figure.add_subplot()
        colors = dict(zip(_AXES, ("tab:blue", "tab:orange", "tab:green")))
        if reference is not None and len(reference):
            for a in _AXES:
                ax.plot(reference["frame"], reference[f"focal_{a}_mm"], "x", color="0.45", markersize=9)
            ax.plot([], [], "x", color="0.45", label="tracked from arrays")
        self._lines = {a: ax.plot([], [], "o-", color=colors[a], label=f"focal {a}")[0] for a in _AXES}
        self._refused = ax.plot([], [], "o", mfc="none", mec="k", markersize=12, label="refused")[0]
        ax.set_xlim(-0.5, n_pairs - 0.5)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("frame pair")
        ax.set_ylabel("mm (C-arm frame)")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        self.figure.tight_layout()
        self._handle = None
        if show:
            from IPython.display import display

            self._handle = display(self.figure, display_id=True)  # None outside IPython

    def __call__(self, record: dict) -> None:
        """Draw one received record (the receiver's ``on_pose``); records without a pose are kept
        but not drawn."""
        with self._lock:
            self.records.append(record)
            posed = [r for r in self.records if r.get("focal_point_mm") is not None]
            pairs = [r["pair_index"] for r in posed]
            focal = np.array([r["focal_point_mm"] for r in posed], dtype=float).reshape(-1, 3)
            for i, a in enumerate(_AXES):
                self._lines[a].set_data(pairs, focal[:, i])
            refused = [k for k, r in enumerate(posed) if not r.get("accepted")]
            self._refused.set_data(np.repeat([pairs[k] for k in refused], 3), focal[refused].ravel())
            self.ax.relim()
            self.ax.autoscale_view(scalex=False)
            if self._handle is not None:
                self._handle.update(self.figure)


def compare_with_tracked(records: list[dict], tracked: pd.DataFrame) -> pd.DataFrame:
    """Each received pose beside the tracked one of the same frames (:func:`track_cine`'s
    table, matched on its ``frame`` = the pair's first plane's frame index): the pair, how it was
    tracked, both verdicts, the received focal point and ``focal_difference_mm`` (NaN where either
    has no pose, or the frame was not tracked)."""
    needed = {"frame", *(f"focal_{a}_mm" for a in _AXES), "accepted"}
    if not needed <= set(tracked.columns):
        raise ValueError(f"tracked must be track_cine's table with columns {sorted(needed)}, got "
                         f"{sorted(tracked.columns)}")
    by_frame = tracked.set_index("frame")
    rows = []
    for r in records:
        frame = int(r["frame_indices"][0])
        focal = np.asarray(r["focal_point_mm"], dtype=float) if r.get("focal_point_mm") is not None else \
            np.full(3, np.nan)
        row = {"pair": int(r["pair_index"]), "frame": frame, "tracking": r.get("tracking"),
               "accepted": bool(r.get("accepted")),
               **{f"focal_{a}_mm": v for a, v in zip(_AXES, focal)},
               "tracked_accepted": None, "focal_difference_mm": math.nan, "latency_s": r["seconds"]["latency"]}
        if frame in by_frame.index:
            ref = by_frame.loc[frame]
            row["tracked_accepted"] = bool(ref["accepted"])
            row["focal_difference_mm"] = float(np.linalg.norm(
                focal - ref[[f"focal_{a}_mm" for a in _AXES]].to_numpy(float)))
        rows.append(row)
    return pd.DataFrame(rows)


def throughput_table(stats: dict) -> pd.DataFrame:
    """The receiver's throughput from its :meth:`~histostudy.lab.FrameReceiver.stats`: frames and
    pairs, frames per second (from the first frame received to the last pose written, and over the
    pose work alone), and the seconds per pair of each stage (decoding, the pose stages, the pose
    in all, the latency from a pair's last frame to its line)."""
    rows = [{"quantity": "frames received", "value": stats["frames_received"]},
            {"quantity": "pairs posed", "value": stats["pairs_processed"]},
            {"quantity": "pairs accepted", "value": stats["pairs_accepted"]},
            {"quantity": "frames/s (first frame to last pose)", "value": stats["frames_per_s"]},
            {"quantity": "frames/s (pose work alone)", "value": stats["pose_frames_per_s"]}]
    rows += [{"quantity": f"seconds per pair: {stage}", "value": seconds}
             for stage, seconds in stats["seconds_per_pair"].items()]
    return pd.DataFrame(rows)


@dataclass(frozen=True, eq=False)
class LiveSection:
    """The cine streamed through the receiver (:func:`live_section`).

    Args:
        records: the receiver's pose records, one per pair.
        stats: the receiver's :meth:`histostudy.lab.FrameReceiver.stats`.
        received_vs_tracked: each received pose beside the tracked one (:func:`compare_with_tracked`;
            ``focal_difference_mm``, mm).
        throughput: the receiver's throughput (:func:`throughput_table`).
        part: the report's part (the live figure, both tables, the stats and the largest focal
            difference, mm).
    """

    records: list
    stats: dict
    received_vs_tracked: pd.DataFrame
    throughput: pd.DataFrame
    part: SectionPart


def live_section(setup: YourDataSetup, tracked: pd.DataFrame, *, show: bool = True,
                 timer: Timer | None = None) -> LiveSection:
    """Notebook 06's live section: as many pairs of the cine as ``tracked`` has rows streamed to the
    receiver (:func:`stream_cine`; poses to ``output_dir/live_poses.jsonl``) while a
    :class:`LiveFocalFigure` draws them over the tracked points, then set beside the tracked poses.

    Args:
        setup: the section's set-up.
        tracked: the ``table`` of :func:`histostudy.study.your_data.tracking_section`.
        show: draw the figure live in IPython.
        timer: ``timer(name)`` -> a context manager timing the stream (``"live stream"``); None: untimed.

    Returns:
        The :class:`LiveSection`.

    Raises:
        RuntimeError: the receiver refused an object.
        TimeoutError: fewer pairs were posed than sent within the wait.
    """
    figure = LiveFocalFigure(len(tracked), reference=tracked, show=show)
    with (timer or (lambda name: contextlib.nullcontext()))("live stream"):
        records, stats = stream_cine(setup.inputs, setup.model, setup.seed,
                                     output_path=setup.output_dir / "live_poses.jsonl", max_pairs=len(tracked),
                                     on_pose=figure)
    compared, throughput = compare_with_tracked(records, tracked), throughput_table(stats)
    part = SectionPart(
        figures={"live_focal_points": (figure.figure, "The focal point of each pair as the DICOM receiver posed it "
                                       "(crosses: tracked from arrays).")},
        tables={"live_poses": (compared, "Each pose received over DICOM beside the one tracked from the same frames "
                               "as arrays (mm)."),
                "receiver_throughput": (throughput, "The DICOM receiver's throughput on the cine.")},
        values={"receiver_stats": stats,
                "live_max_focal_difference_mm": float(compared["focal_difference_mm"].max())})
    return LiveSection(records, stats, compared, throughput, part)
