"""The robots of the targeting study: the in-process UR5e simulation and the simulated UR controller
driven through the real ``ur_rtde`` client (§II-D; docs/architecture.md, "Robots").

Each factory takes the experiment's integer robot seed (the controller's ``--seed``) and the
start joints (rad) and yields a :class:`~histostudy.robot.Robot` as a context manager, so that
the same study seed gives the same moves, and the same numbers, on either robot (up to the float
round trip of the metre/axis-angle boundary, far below 1e-6 mm).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading

import numpy as np

from histostudy.robot import HOME_JOINTS_RAD, SimulatedUR5e
from ._setup import TargetingStudyConfig

__all__ = ["robot_seed", "rtde_robot", "sim_robot"]


def robot_seed(seq: np.random.SeedSequence) -> int:
    """The integer seed of the robot's repeatability noise (the controller's ``--seed``)."""
    return int(seq.generate_state(1)[0])


def sim_robot(config: TargetingStudyConfig):
    """A robot factory for :func:`run_targeting_experiment`: ``SimulatedUR5e`` in process."""

    @contextlib.contextmanager
    def factory(seed: int, initial_joints_rad=HOME_JOINTS_RAD):
        robot = SimulatedUR5e(int(seed), repeatability_mm=config.robot_repeatability_mm,
                              initial_joints_rad=initial_joints_rad)
        try:
            yield robot
        finally:
            robot.close()

    return factory


_HOST_LOCK = threading.Lock()
_HOST_COUNTER = itertools.count(1)


def _loopback_host() -> str:
    """A loopback address of its own per controller (ur_rtde's ports are fixed)."""
    with _HOST_LOCK:
        k = next(_HOST_COUNTER)
    return f"127.{(os.getpid() % 200) + 30}.{(k % 250) + 1}.{(os.getpid() // 200) % 250 + 2}"


def rtde_robot(config: TargetingStudyConfig, *, command_timeout_s: float = 10.0):
    """A robot factory: the simulated UR controller in its own process on a loopback address,
    driven by :class:`~histostudy.robot.RTDERobot` through the real ``ur_rtde`` client.

    The controller's ``--seed`` is the experiment's robot seed, so its repeatability noise is
    drawn exactly as :func:`sim_robot`'s. The controller is stopped when the block ends.
    """
    from histostudy.robot import RTDERobot
    from histostudy.robot.controller import ControllerProcess

    @contextlib.contextmanager
    def factory(seed: int, initial_joints_rad=HOME_JOINTS_RAD):
        proc = ControllerProcess(_loopback_host(), "--seed", str(int(seed)),
                                 "--repeatability-mm", repr(float(config.robot_repeatability_mm)),
                                 "--initial-joints", *(repr(float(q)) for q in initial_joints_rad),
                                 max_lifetime_s=3600)
        try:
            robot = RTDERobot(proc.host, command_timeout_s=command_timeout_s)
            try:
                yield robot
            finally:
                robot.close()
        finally:
            proc.stop()

    return factory
