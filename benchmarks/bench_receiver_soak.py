"""The live receiver over a whole procedure (issue 56): a paced biplane cine for ``--minutes``, with
objects sent again, objects dropped half-way and hostile peers mixed in, and what the receiver
held over time.

A :class:`histostudy.lab.FrameReceiver` on loopback, live (``max_queued_pairs=1``: the newest
pair), its pose work the tests' stub tracker (``--tracker stub``, the network side's figures) or
the shipped learned stages (``--tracker learned``, on the paper's full-size views), receives one
C-arm's cine: plane A's and B's frame ``k`` as two single-frame XA objects at ``k / --fps`` s, in
one association. Every ``--resend-every``-th pair is stored a second time (a C-STORE repeated
after a lost response), every ``--drop-every``-th pair is preceded by a connection that sends half
an object and drops, and ``--hostile-per-min`` hostile associations (tests/lab/receiver_stub.py's
kinds) arrive at random times. Every 5 s the receiver's counts, its process's resident memory
(RSS) and threads are sampled.

Prints: frames sent (and the pace reached) / answered success / refused or unanswered (must be 0) /
posed (in a pair's line) / sent again and answered as duplicates; frames posed twice (must be 0);
the latency's p50 / p99; RSS at minute 5 and at the end, and its growth; threads before, at the
end and after the stop; the CPU. ``--plot PATH`` draws RSS, threads and the latency over time.
Usage: ``python benchmarks/bench_receiver_soak.py --minutes 30 --plot soak.png``. Asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import threading
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "lab"))  # the stub clients

from receiver_stub import StubTracker, receiver_with, rss_bytes, run_soak, small_views  # noqa: E402

from histostudy.core import machine_summary  # noqa: E402
from histostudy.imaging import default_biplane  # noqa: E402
from histostudy.lab import FrameReceiver, ReceiverConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0, help="how long the cine runs (default 30)")
    parser.add_argument("--fps", type=float, default=15.0, help="frames per second per plane (default 15)")
    parser.add_argument("--resend-every", type=int, default=50, help="every n-th pair stored twice (0: none)")
    parser.add_argument("--drop-every", type=int, default=100, help="every n-th pair after a drop (0: none)")
    parser.add_argument("--hostile-per-min", type=float, default=30.0, help="hostile associations per minute")
    parser.add_argument("--tracker", choices=("stub", "learned"), default="stub")
    parser.add_argument("--seed", type=int, default=20261128)
    parser.add_argument("--plot", default=None, help="a PNG of RSS, threads and latency over time")
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # every refusal is logged: not what is measured
    warnings.filterwarnings("ignore")

    views = small_views() if args.tracker == "stub" else default_biplane()
    threads_before, rss_start = len(threading.enumerate()), rss_bytes()
    with tempfile.TemporaryDirectory() as folder:
        if args.tracker == "stub":
            receiver = receiver_with(views, Path(folder), StubTracker(keep_images=False), max_queued_pairs=1,
                                     network_timeout_s=5.0)
        else:
            receiver = FrameReceiver(views, ReceiverConfig(output_path=Path(folder) / "poses.jsonl", port=0,
                                                           max_queued_pairs=1, network_timeout_s=5.0))
        with receiver:
            soak = run_soak(receiver, views, seconds=60.0 * args.minutes, fps=args.fps, resend_every=args.resend_every,
                            drop_every=args.drop_every, hostile_per_min=args.hostile_per_min, seed=args.seed)
        lines = [json.loads(line) for line in (Path(folder) / "poses.jsonl").read_text().splitlines()]
    threads_after = len(threading.enumerate())

    sent, stats, samples = soak["sent"], soak["stats"], soak["samples"]
    posed = [uid for line in lines for uid in line["instance_uids"]]
    refused = sum(n for status, n in sent["statuses"].items() if status != 0)
    at5 = next((s["rss"] for s in samples if s["t_s"] >= 300.0), samples[0]["rss"])
    rss_end = samples[-1]["rss"]
    print(machine_summary())
    print(f"{args.minutes:g} min at {args.fps:g} frames/s per plane; tracker {args.tracker}; "
          f"{sum(soak['hostile'].values())} hostile associations")
    print(f"frames sent {sent['frames']} ({sent['frames'] / 2 / (60.0 * args.minutes):.1f} pairs/s; +{sent['resent']} "
          f"sent again), answered success {sent['statuses'][0]}, refused or unanswered {refused}; in a posed pair "
          f"{len(posed)}; objects answered as duplicates {stats['objects_duplicate']}; the receiver's frames "
          f"{stats['frames_received']} (hostile objects it took included)")
    print(f"frames posed twice {len(posed) - len(set(posed))}; pairs posed {stats['pairs_processed']}, dropped for a "
          f"newer one {stats['pairs_dropped_stale']}; drops mid-object {sent['dropped']}")
    latency = stats["latency_s"]
    print(f"latency s: p50 {latency['p50']}, p99 {latency['p99']}, max {latency['max']}")
    print(f"RSS at the start {rss_start / 2 ** 20:.1f} MiB, at minute 5 (or the first sample) {at5 / 2 ** 20:.1f} MiB, "
          f"at the end {rss_end / 2 ** 20:.1f} MiB ({100.0 * (rss_end - at5) / at5:+.1f} %)")
    print(f"threads: before {threads_before}, at the end {soak['threads_end']}, after the stop {threads_after}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        minutes = [s["t_s"] / 60.0 for s in samples]
        fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
        axes[0].plot(minutes, [s["rss"] / 2 ** 20 for s in samples])
        axes[0].set_ylabel("RSS (MiB)")
        axes[1].plot(minutes, [s["threads"] for s in samples])
        axes[1].set_ylabel("threads")
        axes[2].plot(minutes, [s["p99_s"] for s in samples])
        axes[2].set_ylabel("latency p99 (s)")
        axes[2].set_xlabel("minutes")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
