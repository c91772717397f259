"""A minute of moving cine through the pose receiver (§II-A live frames; docs/tracking.md, "A minute
of moving cine through the receiver").

Writes (or reuses, when ``--folder`` already holds one) the cine of
:func:`histostudy.study.your_data.moving_cine.write_moving_cine`: the robot carrying the physical transducer
between the margin points of the study at up to ``--speed-mm-s``, ``--seconds`` long at ``--fps``
frames per second, single-frame DICOM XA per plane and frame. Then, for each of ``--modes`` (``fast``:
the receiver's default, ``Tracker``'s fast path; ``full``: every pair on the full frames), streams it
at its frame rate to a :class:`histostudy.lab.FrameReceiver` on loopback with ``--max-queued-pairs``
(:func:`histostudy.study.your_data.moving_cine_live.stream_moving_cine`; ``--pipeline``: the receiver's pipeline
on; ``--retries on|off``: the tracker's retries of a refused estimate from scratch;
``--scratch-full-frames on|off``: its second and third steps on the full frames; ``--refinement
paper|fast``: the tracker's mode; ``--sender process|thread``: the sender in a process of its own, the
default, or on a thread of the receiver's process) and prints the counts, rates, latency
and focal error (:func:`~histostudy.study.your_data.moving_cine_live.count_table`), the seconds per posed pair
of each stage, the latency's percentiles (p50, p90, p99, max) and the pairs dropped from the
receiver's stats, and per kind of update (warm, from scratch, re-acquired) the pose seconds, latency and
focal error. Writes ``<mode>_frames.csv``, ``<mode>_counts.csv``, ``<mode>_stats.json`` and
``<mode>_focal_error.png`` into ``--output``. The CPU and its instruction sets come first, the load
average before and after says how busy the machine was; ``--isa avx2`` runs it as on a CPU with
AVX2 only (:func:`histostudy.core.run_restricted_to`).

Usage: ``.venv/bin/python benchmarks/bench_moving_cine.py --folder /tmp/cine --output /tmp/out [--isa avx2]``
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import pandas as pd

from histostudy.core import BENCHMARK_ISAS, atomic_write_json, machine_summary, run_restricted_to, to_jsonable
from histostudy.pose import TrackingConfig
from histostudy.study.your_data.moving_cine import load_moving_cine, write_moving_cine
from histostudy.study.your_data.moving_cine_live import count_table, frame_table, plot_focal_error, stream_moving_cine
from histostudy.transducer import TransducerModel


def latency_line(stats: dict) -> str:
    """The latency's percentiles (s, from a pair's last frame received to its pose line) and the
    pairs dropped, from the receiver's stats."""
    latency = stats["latency_s"]
    figures = ", ".join(f"{k} {latency[k]:.3f}" for k in ("p50", "p90", "p99", "max") if latency[k] is not None)
    return (f"latency s: {figures or 'no pose'} over {latency['n']} poses; pairs posed {stats['pairs_processed']}, "
            f"dropped {stats['pairs_skipped']} ({stats['pairs_dropped_stale']} for a newer pair)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", required=True, help="the cine's folder (written unless it holds one)")
    parser.add_argument("--output", required=True, help="folder for the tables, stats and figures")
    parser.add_argument("--seed", type=int, default=20230119, help="the cine's seed (default: the study's)")
    parser.add_argument("--seconds", type=float, default=60.0, help="cine length, s (default 60)")
    parser.add_argument("--fps", type=float, default=7.5, help="frame rate, frames/s (default 7.5)")
    parser.add_argument("--speed-mm-s", type=float, default=10.0, help="the robot's peak speed, mm/s (default 10)")
    parser.add_argument("--modes", default="fast,full", help="comma-separated: fast, full (default both)")
    parser.add_argument("--max-queued-pairs", type=int, default=1,
                        help="the receiver's queue (default 1, the receiver's own: the newest pair only)")
    parser.add_argument("--tracker-seed", type=int, default=0, help="the receiver's tracker seed (default 0)")
    parser.add_argument("--pipeline", action="store_true",
                        help="the receiver's pipeline (FrameReceiver(pipeline=True): the next pair segmented ahead)")
    parser.add_argument("--retries", choices=("default", "on", "off"), default="default",
                        help="the tracker's retries of a refused estimate from scratch "
                             "(PoseConfig.retry_hypotheses; default: the receiver's own)")
    parser.add_argument("--scratch-full-frames", choices=("default", "on", "off"), default="default",
                        help="a refused estimate from scratch tried again on the full frames "
                             "(TrackingConfig.scratch_full_frames; default: the receiver's own)")
    parser.add_argument("--refinement", choices=("default", "paper", "fast"), default="default",
                        help="PoseConfig.mode of the tracker (default: the receiver's own, fast)")
    parser.add_argument("--sender", choices=("process", "thread"), default="process",
                        help="where the C-arm's sender runs: a process of its own (default; a C-arm is another "
                             "machine, here sharing the cores) or a thread of the receiver's process")
    parser.add_argument("--isa", choices=BENCHMARK_ISAS, default="native",
                        help="avx2: run as on a CPU with AVX2 only (the command again, its libraries restricted)")
    args = parser.parse_args()
    run_restricted_to(args.isa)
    print(machine_summary(), flush=True)
    retries = {} if args.retries == "default" else {"retry_hypotheses": args.retries == "on"}
    fast = True if args.scratch_full_frames == "default" else TrackingConfig(
        scratch_full_frames=args.scratch_full_frames == "on")
    if args.refinement != "default":
        retries["mode"] = args.refinement
    pd.set_option("display.width", 200)

    folder, out = Path(args.folder), Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if (folder / "cine.json").is_file():
        cine = load_moving_cine(folder)
        print(f"reusing the cine in {folder}: {cine.n_frames} frames at {cine.fps:g} frames/s", flush=True)
    else:
        t0 = time.perf_counter()
        cine = write_moving_cine(folder, seed=args.seed, duration_s=args.seconds, fps=args.fps,
                                 max_speed_mm_s=args.speed_mm_s,
                                 progress=lambda k, n: print(f"rendered {k}/{n}", flush=True) if k % 50 == 0 else None)
        print(f"rendered {cine.n_frames} pairs in {time.perf_counter() - t0:.0f} s", flush=True)
    model = TransducerModel.build(spacing_mm=0.47)
    for mode in args.modes.split(","):
        if mode not in ("fast", "full"):
            raise SystemExit(f"--modes must name fast and/or full, got {mode!r}")
        print(f"== {mode}: load average before {os.getloadavg()}", flush=True)
        t0 = time.perf_counter()
        run = stream_moving_cine(cine, model, args.tracker_seed, output_path=out / f"{mode}_poses.jsonl",
                                 fast=fast if mode == "fast" else False, max_queued_pairs=args.max_queued_pairs,
                                 pipeline=args.pipeline, sender_process=args.sender == "process", **retries)
        frames = frame_table(run, cine)
        counts = count_table(run, frames)
        frames.to_csv(out / f"{mode}_frames.csv", index=False)
        counts.to_csv(out / f"{mode}_counts.csv", index=False)
        atomic_write_json(out / f"{mode}_stats.json", to_jsonable({
            "stats": run.stats, "stream_s": run.stream_s, "wall_s": run.wall_s,
            "late_s": [o.late_s for o in run.sent]}))
        plot_focal_error(frames, title=f"{cine.n_frames / cine.fps:g} s at {cine.fps:g} frames/s, {mode}").savefig(
            out / f"{mode}_focal_error.png", dpi=110)
        print(f"load average after {os.getloadavg()}; {time.perf_counter() - t0:.1f} s", flush=True)
        print(counts.to_string(), flush=True)
        print("seconds per posed pair:", json.dumps({k: round(v, 3) for k, v in run.stats["seconds_per_pair"].items()}))
        print(latency_line(run.stats), flush=True)
        posed = frames[frames["status"] == "posed"]
        print(posed.groupby("tracking")[["pose_s", "latency_s", "focal_error_mm"]].median().to_string(), flush=True)


if __name__ == "__main__":
    main()
