"""The live receiver under a hostile network (docs/your-data.md, "Live frames on the hospital network"):
the fuzz of tests/lab/test_receiver_fuzz.py at a larger size, with its figures.

A :class:`histostudy.lab.FrameReceiver` on loopback (its pose work the tests' stub tracker, so that
the figures are the network side's: ``max_queued_pairs=None``, ``--network-timeout-s``, data sets
bounded at ``--max-object-mib``) receives ``--hostile`` hostile associations (default 600), drawn
from every kind of tests/lab/receiver_stub.py's ``HOSTILE`` with ``--seed`` (each replays alone:
``receiver_stub.hostile(port, views, seed, index, limits)``), ``--concurrency`` (default 40) at
once; beside each batch a legitimate sender stores a good pair, and after it the receiver must
answer a C-ECHO and have posed that pair.

Prints: the hostile associations per kind and their outcomes, the answers not acceptable (to
replay), the crashes (failed C-ECHOs, good pairs refused or not posed, exceptions that ended a
thread, handlers' exceptions), the good pairs posed / sent, the threads before the receiver started
and after it stopped, the process's resident memory (RSS) before, after the first batch and at the
end, the seconds, and the CPU. Usage: ``python benchmarks/bench_receiver_fuzz.py [--hostile 600]
[--concurrency 40]``. Asserts nothing.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "lab"))  # the fuzz's clients

from receiver_stub import StubTracker, read_lines, receiver_with, rss_bytes, run_fuzz, small_views  # noqa: E402

from histostudy.core import machine_summary  # noqa: E402


def mib(n: int | None) -> str:
    return "n/a" if n is None else f"{n / 2 ** 20:.1f} MiB"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hostile", type=int, default=600, help="hostile associations (default 600)")
    parser.add_argument("--concurrency", type=int, default=40, help="hostile associations at once (default 40)")
    parser.add_argument("--seed", type=int, default=20240506)
    parser.add_argument("--network-timeout-s", type=float, default=2.0)
    parser.add_argument("--max-object-mib", type=float, default=1.0, help="the receiver's data set bound")
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # each broken PDU is logged with its traceback: not what is timed
    warnings.filterwarnings("ignore", "End of file reached before delimiter")  # garbage_pixel_length's

    views = small_views()
    threads_before, rss_before = len(threading.enumerate()), rss_bytes()
    with tempfile.TemporaryDirectory() as folder:
        receiver = receiver_with(views, Path(folder), StubTracker(keep_images=False), max_queued_pairs=None,
                                 network_timeout_s=args.network_timeout_s, warm_up=False)
        receiver.max_object_bytes = int(args.max_object_mib * 2 ** 20)
        with receiver:
            report = run_fuzz(receiver, views, seed=args.seed, n_hostile=args.hostile, concurrency=args.concurrency,
                              measure=rss_bytes)
        t_stop = time.perf_counter()
        while len(threading.enumerate()) > threads_before and time.perf_counter() - t_stop < 30:
            time.sleep(0.05)  # the associations' threads end within the network timeout
        lines = read_lines(Path(folder) / "poses.jsonl")
    stats = receiver.stats()

    print(f"receiver fuzz: {args.hostile} hostile associations, {args.concurrency} at once, seed {args.seed}, "
          f"network timeout {args.network_timeout_s} s, data sets bounded at {args.max_object_mib} MiB")
    print(f"{'kind':<22} {'n':>5}  outcomes")
    for kind, n in report["kinds"].items():
        outcomes = ", ".join(f"{k} {v}" for k, v in sorted(report["outcomes"][kind].items(), key=lambda kv: -kv[1]))
        print(f"{kind:<22} {n:>5}  {outcomes}")
    print(f"answers not acceptable: {len(report['failures'])} {report['failures'][:10]}")
    print(f"crashes: {report['crashes']} {report['crash_kinds']}")
    posed = sum(line["instance_uids"] in report["good_uids"] and "error" not in line for line in lines)
    print(f"good pairs posed / sent: {posed} / {report['good_sent']} (lines {len(lines)})")
    print(f"receiver counts: objects received {stats['objects_received']} = accepted {stats['objects_accepted']} "
          f"+ sent again {stats['objects_duplicate']} + rejected {stats['objects_rejected']} {stats['rejections']}; "
          f"connections {stats['connections']}, "
          f"associations {stats['associations']}, aborted {stats['associations_aborted']}, rejected at pynetdicom's "
          f"limit of associations at once {stats['associations_rejected']} (tried again); frames "
          f"{stats['frames_received']} = 2 x {stats['pairs_completed']} paired + {stats['frames_unpaired']} unpaired")
    print(f"threads: {threads_before} before the receiver started, {len(threading.enumerate())} after it stopped")
    memory = report["memory"]
    print(f"RSS: {mib(rss_before)} before, {mib(memory['after_first'])} after the first batch, "
          f"{mib(memory['after_all'])} after all")
    print(f"seconds: {report['seconds']:.1f} ({args.hostile / report['seconds']:.0f} hostile associations/s)")
    print(machine_summary())


if __name__ == "__main__":
    main()
