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
import collections
import datetime as dt
import json
import logging
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "lab"))  # the stub clients

from receiver_stub import (  # noqa: E402
    HOSTILE,
    StubTracker,
    dropped_mid_pdata,
    hostile,
    receiver_with,
    rss_bytes,
    small_views,
)

from histostudy.core import machine_summary  # noqa: E402
from histostudy.imaging import default_biplane  # noqa: E402
from histostudy.imaging.io._xa import xa_dataset  # noqa: E402
from histostudy.lab import FrameReceiver, ReceiverConfig  # noqa: E402

T0 = dt.datetime(2026, 11, 28, 9, 0, 0)
#: The hostile kinds mixed in: all but a stalled PDU (it holds its connection for the network
#: timeout) and an oversize object (it streams gigabytes at the receiver's bound on a data set).
KINDS = tuple(k for k in HOSTILE if k not in ("stalled_pdu", "oversize_pixels"))


def pair(views, k: int, fps: float, rng: np.random.Generator) -> list:
    """Plane A's and B's frame ``k`` of the cine, taken ``k / fps`` s after T0."""
    when = T0 + dt.timedelta(seconds=k / fps)
    return [xa_dataset(v, rng.integers(100, 4000, size=v.shape).astype(np.uint16), acquisition_time=when,
                       uid_seed=f"soak/{k}/{v.name}") for v in views]


def send_cine(port: int, views, args, stop: threading.Event, sent: dict) -> None:
    """The C-arm: one association, each pair at its time, some stored twice, some after a drop."""
    from pynetdicom import AE

    rng = np.random.default_rng(args.seed)
    ae = AE(ae_title="CARM")
    ae.add_requested_context("1.2.840.10008.5.1.4.1.1.12.1", "1.2.840.10008.1.2.1")
    assoc = ae.associate("127.0.0.1", port, ae_title="HISTOSTUDY")
    t_start, k = time.monotonic(), 0
    try:
        while not stop.is_set() and assoc.is_established:
            wait = t_start + k / args.fps - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            if args.drop_every and k % args.drop_every == args.drop_every - 1:
                try:
                    dropped_mid_pdata(port, rng, views, None)
                except OSError:
                    pass
                sent["dropped"] += 1
            objects = pair(views, k, args.fps, rng)
            times = 2 if args.resend_every and k % args.resend_every == args.resend_every - 1 else 1
            for _ in range(times):
                for ds in objects:
                    status = assoc.send_c_store(ds)
                    sent["statuses"][int(getattr(status, "Status", -1))] += 1
            sent["frames"] += 2
            sent["resent"] += 2 * (times - 1)
            k += 1
    finally:
        if assoc.is_established:
            assoc.release()


def send_hostile(receiver, views, args, stop: threading.Event, outcomes: dict) -> None:
    """Hostile associations at random times, ``--hostile-per-min`` on average."""
    rng = np.random.default_rng(args.seed + 1)
    limits = SimpleNamespace(max_pdu_bytes=receiver.max_pdu_bytes, max_object_bytes=receiver.max_object_bytes,
                             stream_bytes=1 << 20)
    index = 0
    while not stop.wait(rng.exponential(60.0 / args.hostile_per_min)):
        kind, outcome = hostile(receiver.port, views, args.seed, index, limits, kinds=KINDS)
        outcomes[(kind, outcome)] = outcomes.get((kind, outcome), 0) + 1
        index += 1


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
    threads_before = len(threading.enumerate())
    sent = {"frames": 0, "resent": 0, "dropped": 0, "statuses": collections.Counter()}
    outcomes: dict = {}
    samples = []
    with tempfile.TemporaryDirectory() as folder:
        if args.tracker == "stub":
            receiver = receiver_with(views, Path(folder), StubTracker(keep_images=False), max_queued_pairs=1,
                                     network_timeout_s=5.0)
        else:
            receiver = FrameReceiver(views, ReceiverConfig(output_path=Path(folder) / "poses.jsonl", port=0,
                                                           max_queued_pairs=1, network_timeout_s=5.0))
        with receiver:
            stop = threading.Event()
            workers = [threading.Thread(target=send_cine, args=(receiver.port, views, args, stop, sent)),
                       threading.Thread(target=send_hostile, args=(receiver, views, args, stop, outcomes))]
            t0 = time.monotonic()
            for w in workers:
                w.start()
            while time.monotonic() - t0 < 60.0 * args.minutes:
                time.sleep(5.0)
                stats = receiver.stats()
                samples.append({"t_s": time.monotonic() - t0, "rss": rss_bytes(), "threads": len(threading.enumerate()),
                                "p99_s": stats["latency_s"]["p99"], "frames": stats["frames_received"]})
            stop.set()
            for w in workers:
                w.join(60)
            time.sleep(1.0)
            threads_end = len(threading.enumerate())
            stats = receiver.stats()
        lines = [json.loads(line) for line in (Path(folder) / "poses.jsonl").read_text().splitlines()]
    threads_after = len(threading.enumerate())

    posed = [uid for line in lines for uid in line["instance_uids"]]
    twice = len(posed) - len(set(posed))
    at5 = next((s["rss"] for s in samples if s["t_s"] >= 300.0), samples[0]["rss"] if samples else None)
    rss_end = samples[-1]["rss"] if samples else None
    print(machine_summary())
    print(f"{args.minutes:g} min at {args.fps:g} frames/s per plane; tracker {args.tracker}; "
          f"{sum(outcomes.values())} hostile associations")
    refused = sum(n for status, n in sent["statuses"].items() if status != 0)
    print(f"frames sent {sent['frames']} ({sent['frames'] / 2 / (60.0 * args.minutes):.1f} pairs/s; +{sent['resent']} "
          f"sent again), answered success {sent['statuses'][0]}, refused or unanswered {refused}; in a posed pair "
          f"{len(posed)}; objects answered as duplicates {stats['objects_duplicate']}; the receiver's frames "
          f"{stats['frames_received']} (hostile objects it took included)")
    print(f"frames posed twice {twice}; pairs posed {stats['pairs_processed']}, dropped for a newer one "
          f"{stats['pairs_dropped_stale']}; drops mid-object {sent['dropped']}")
    latency = stats["latency_s"]
    print(f"latency s: p50 {latency['p50']}, p99 {latency['p99']}, max {latency['max']}")
    if at5 and rss_end:
        print(f"RSS at minute 5 {at5 / 2 ** 20:.1f} MiB, at the end {rss_end / 2 ** 20:.1f} MiB "
              f"({100.0 * (rss_end - at5) / at5:+.1f} %)")
    print(f"threads: before {threads_before}, at the end {threads_end}, after the stop {threads_after}")
    if args.plot and samples:
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
