"""Time of one hand-eye calibration (§II-C, eq. 8) against OpenCV's Daniilidis on the same poses.

Measures, on this machine, for 4 (the paper's count), 12 and 30 poses with 0.5 mm / 0.2° pose noise:

- ``histostudy.calibration.calibrate``: validation of every pose, all n(n-1)/2 motions, the eq. 8
  null space, T_carm_base, and the per-pose and per-motion residuals;
- the baseline, measured in the same run: ``cv2.calibrateHandEye(..., method=
  cv2.CALIB_HAND_EYE_DANIILIDIS)`` on the same poses (C++; X only, no T_carm_base, no residuals,
  inputs converted to its list-of-arrays form outside the timing); the ratio is ours / OpenCV.

Usage: ``python benchmarks/bench_handeye.py [--repeats N] [--seed S]``. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import numpy as np

from histostudy import calibration as he
from histostudy.geometry import transforms as g


def best_median(fn, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    ms = np.asarray(times) * 1000.0
    return float(np.median(ms)), float(ms.min())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print(f"python {platform.python_version()}, numpy {np.__version__}, opencv {cv2.__version__}, "
          f"{os.cpu_count()} CPUs, {args.repeats} repeats")
    for n in (4, 12, 30):
        X, Y = g.random_transform(rng, 200.0), g.random_transform(rng, 800.0)
        F = [g.random_transform(rng, 400.0) for _ in range(n)]
        C = [he.perturb_pose(Y @ f @ X, 0.5, 0.2, rng) for f in F]
        Ci = [np.linalg.inv(c) for c in C]
        cv_args = ([f[:3, :3] for f in F], [f[:3, 3] for f in F], [c[:3, :3] for c in Ci], [c[:3, 3] for c in Ci])
        ours_med, ours_best = best_median(lambda F=F, C=C: he.calibrate(F, C), args.repeats)
        cv_med, cv_best = best_median(
            lambda cv_args=cv_args: cv2.calibrateHandEye(*cv_args, method=cv2.CALIB_HAND_EYE_DANIILIDIS), args.repeats
        )
        print(f"{n:3d} poses ({n * (n - 1) // 2:4d} motions): calibrate median {ours_med:7.3f} ms "
              f"(best {ours_best:7.3f}); OpenCV Daniilidis median {cv_med:7.3f} ms (best {cv_best:7.3f}); "
              f"ratio {ours_med / cv_med:5.1f}x")


if __name__ == "__main__":
    main()
