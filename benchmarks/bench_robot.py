"""Round-trip time of a linear move through the real ur_rtde client on loopback (§II-C robot layer).

Measures, on this machine, with the simulated controller in its own process
(``python -m histostudy.robot.controller``, no repeatability noise, instant motion):

- ``RTDERobot.move_linear``: the whole checked move (workspace, local IK, the controller's
  ``isPoseWithinSafetyLimits`` and ``getInverseKinematicsHasSolution``, ``moveL``, waiting until the
  received pose has settled) - the figure the issue targets (<= 50 ms);
- the bare ``RTDEControlInterface.moveL`` call (register handshake only);
- the baseline, measured in the same run: ``SimulatedUR5e.move_linear`` in process, the same
  planning without any network; the ratio is RTDE / baseline (the protocol's overhead factor).

The moves alternate between two poses 20 mm apart. Usage:
``python benchmarks/bench_robot.py [--moves N] [--host 127.0.0.9]``. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from histostudy.robot import RTDERobot, SimulatedUR5e, pose_from_transform
from histostudy.robot.controller import ControllerProcess


def stats(times_s: list[float]) -> str:
    ms = np.asarray(times_s) * 1000.0
    return f"median {np.median(ms):6.2f} ms, p90 {np.percentile(ms, 90):6.2f} ms, best {ms.min():6.2f} ms"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--moves", type=int, default=60, help="moves per measurement")
    parser.add_argument("--host", default="127.0.0.9", help="loopback address for the simulated controller")
    args = parser.parse_args(argv)
    n = max(2, args.moves)
    print(f"python {platform.python_version()}, {os.cpu_count()} CPUs, ur_rtde on {args.host}, {n} moves each")

    sim = SimulatedUR5e(0, repeatability_mm=0.0)
    a = sim.tcp_pose()
    b = a.copy()
    b[:3, 3] += [20.0, 0.0, 0.0]
    poses = [b if i % 2 == 0 else a for i in range(n)]

    baseline = []
    for T in poses:
        t0 = time.perf_counter()
        sim.move_linear(T, 250.0, 1200.0)
        baseline.append(time.perf_counter() - t0)

    with ControllerProcess(args.host, "--repeatability-mm", "0") as proc:
        robot = RTDERobot(proc.host)
        checked = []
        for T in poses:
            t0 = time.perf_counter()
            robot.move_linear(T, 250.0, 1200.0)
            checked.append(time.perf_counter() - t0)
        control = robot._control  # the bare client call, for the breakdown
        bare = []
        for T in poses:
            pose = pose_from_transform(T)
            t0 = time.perf_counter()
            ok = control.moveL(pose, 0.25, 1.2)
            bare.append(time.perf_counter() - t0)
            assert ok, "moveL returned False"
        robot.close()

    base_ms = np.median(baseline) * 1000.0
    chk_ms = np.median(checked) * 1000.0
    print(f"baseline SimulatedUR5e.move_linear (in process): {stats(baseline)}")
    print(f"RTDERobot.move_linear (checked, settled):        {stats(checked)}   target <= 50 ms: "
          f"{'met' if chk_ms <= 50.0 else 'NOT met'}")
    print(f"bare RTDEControlInterface.moveL:                 {stats(bare)}")
    print(f"ratio RTDERobot / in-process baseline (median):  {chk_ms / base_ms:5.1f}x")


if __name__ == "__main__":
    main()
