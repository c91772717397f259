"""Throughput of the Monte-Carlo sweeps on a dask LocalCluster beside the sequential run (no paper
section; the executor of ``histostudy.core.run_sweep``).

Measures, on this machine, each against the sequential baseline run in the same process:

- ``calibration.calibration_sensitivity`` (one task per trial: the hand-eye calibrations of
  every noise level, in chunks of trials; the draws, about a third of the sequential time,
  stay in this process);
- optionally ``study.robustness_sweep`` with the oracle stages (one task per random pose: two
  renders and one pose estimate, seconds each).

For each: the sequential seconds, the seconds on a LocalCluster of ``--workers`` processes that
was started beforehand (warm: the sweep's own cost) and the ratio sequential / cluster; the seconds
of ``executor="local:<workers>"``, which starts and closes its cluster (cold); and whether the
rows are the same bit for bit (``seconds``, the pose sweep's timing column, aside).

Usage: ``python benchmarks/bench_sweeps.py [--trials N] [--workers W] [--poses P]``. Prints
figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import time

import numpy as np
import pandas as pd

from histostudy.calibration import calibration_sensitivity


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def same_rows(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    drop = [c for c in ("seconds",) if c in a.columns]
    try:
        pd.testing.assert_frame_equal(a.drop(columns=drop), b.drop(columns=drop), check_exact=True)
    except AssertionError:
        return False
    return True


def report(name: str, sweep, address: str, workers: int) -> None:
    sequential, t_seq = timed(lambda: sweep("sequential"))
    warm, t_warm = timed(lambda: sweep(address))
    cold, t_cold = timed(lambda: sweep(f"local:{workers}"))
    print(f"{name}: {len(sequential)} rows")
    print(f"  sequential                      {t_seq:8.2f} s")
    print(f"  LocalCluster, {workers} workers (warm)    {t_warm:8.2f} s   "
          f"ratio sequential/cluster {t_seq / t_warm:5.2f}")
    print(f"  LocalCluster, {workers} workers (cold)    {t_cold:8.2f} s   "
          f"ratio sequential/cluster {t_seq / t_cold:5.2f}   (starts and closes its cluster)")
    print(f"  same rows bit for bit: warm {same_rows(sequential, warm)}, cold {same_rows(sequential, cold)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=100, help="calibration trials per condition (default 100)")
    parser.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    parser.add_argument("--poses", type=int, default=4, help="random poses of the robustness sweep; 0 skips it")
    args = parser.parse_args()
    for name, value in (("--trials", args.trials), ("--workers", args.workers)):
        if value < 1:
            parser.error(f"{name} must be >= 1, got {value}")
    if args.poses < 0:
        parser.error(f"--poses must be >= 0, got {args.poses}")

    from distributed import LocalCluster

    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, numpy {np.__version__}, "
          f"load average {os.getloadavg()[0]:.1f} (other processes share the CPUs: ratios move with it)")
    cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR)
    try:
        address = cluster.scheduler_address
        levels = ((0.25, 0.1), (0.5, 0.2), (1.0, 0.4))
        report(f"calibration_sensitivity, poses (4, 8, 12) x 3 noise levels x {args.trials} trials",
               lambda ex: calibration_sensitivity((4, 8, 12), levels, n_trials=args.trials, rng=20230119,
                                                  executor=ex), address, args.workers)
        if args.poses:
            from histostudy.imaging import default_biplane
            from histostudy.learning import OracleOrientation
            from histostudy.study.pose import robustness_sweep
            from histostudy.study.pose.experiments import PoseStudyConfig
            from histostudy.transducer import TransducerModel

            model = TransducerModel.build(spacing_mm=0.47)
            physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
            kwargs = dict(pose_model=model, render_model=model, physical=physical, views=default_biplane(),
                          seed=11, config=PoseStudyConfig(n_splats=1), inits=("robust",),
                          orientation=OracleOrientation())
            report(f"robustness_sweep, {args.poses} poses, oracle stages, 'robust' initialisation",
                   lambda ex: robustness_sweep(args.poses, executor=ex, **kwargs), address, args.workers)
    finally:
        cluster.close()
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
