"""The robots of the targeting study (§II-D; docs/architecture.md, "Robots"): the in-process UR5e
simulation and the simulated UR controller driven through ``ur_rtde``, both seeded by the
experiment's integer robot seed, and an arm whose true kinematics differ from its nominal DH
table (:class:`KinematicError`, :class:`InaccurateArm`). Lengths in mm, angles in rad.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import threading
from dataclasses import dataclass

import numpy as np

from histostudy.robot import HOME_JOINTS_RAD, UR5E, SimulatedUR5e, forward_kinematics
from histostudy.robot.kinematics import DHSpec

from .setup import TargetingStudyConfig

__all__ = ["InaccurateArm", "KinematicError", "reported_flange_pose", "robot_seed", "rtde_robot", "sim_robot"]


@dataclass(frozen=True, eq=False)
class KinematicError:
    """An arm's true DH parameters less its nominal table's.

    Args:
        d_mm: the link offsets' errors (6, mm).
        a_mm: the link lengths' errors (6, mm).
        alpha_rad: the twists' errors (6, rad).
        theta_rad: the joint zero offsets (6, rad).
    """

    d_mm: np.ndarray
    a_mm: np.ndarray
    alpha_rad: np.ndarray
    theta_rad: np.ndarray

    @classmethod
    def from_normals(cls, normals, *, length_sd_mm: float, angle_sd_rad: float) -> KinematicError:
        """Standard normals scaled by the lengths' SD and the angles', so that a magnitude changes no draw.

        Args:
            normals: standard normals (4, 6: d, a, alpha, theta).
            length_sd_mm: the lengths' SD (mm).
            angle_sd_rad: the angles' SD (rad).

        Returns:
            The :class:`KinematicError`.

        Raises:
            ValueError: ``normals`` not a finite (4, 6) array.
        """
        z = np.asarray(normals, dtype=np.float64)
        if z.shape != (4, 6) or not np.all(np.isfinite(z)):
            raise ValueError(f"normals must be a finite (4, 6) array (d, a, alpha, theta), got shape {z.shape}")
        return cls(length_sd_mm * z[0], length_sd_mm * z[1], angle_sd_rad * z[2], angle_sd_rad * z[3])

    def physical_dh(self, dh: DHSpec = UR5E) -> DHSpec:
        """The arm's true table.

        Args:
            dh: the nominal table (default the UR5e's).

        Returns:
            ``dh`` plus the length and twist errors (mm, rad).
        """
        return DHSpec(tuple(np.asarray(dh.d_mm) + self.d_mm), tuple(np.asarray(dh.a_mm) + self.a_mm),
                      tuple(np.asarray(dh.alpha_rad) + self.alpha_rad))

    def flange_pose(self, joints_rad, dh: DHSpec = UR5E) -> np.ndarray:
        """Where the flange really is at the encoders' reading.

        Args:
            joints_rad: the encoders' joint angles (6, rad).
            dh: the nominal table (default the UR5e's).

        Returns:
            ``T_base_flange`` (4x4, mm).
        """
        return forward_kinematics(np.asarray(joints_rad, dtype=np.float64) + self.theta_rad, self.physical_dh(dh))


class InaccurateArm:
    """A robot whose arm is not its controller's model (the simulation's view of a real arm).

    The wrapped robot plans every move and reads its joints through the nominal table, as a UR
    controller does; the flange sits where the :class:`KinematicError` puts it. ``flange_pose``,
    ``tcp_pose`` and ``move_linear``'s return are the TRUE poses; :meth:`reported_flange_pose` is what
    the controller reports. Every other attribute is the wrapped robot's.

    Args:
        robot: the wrapped robot (e.g. a :class:`~histostudy.robot.SimulatedUR5e`).
        error: the arm's :class:`KinematicError`.

    Raises:
        TypeError: ``error`` is not a KinematicError.
    """

    def __init__(self, robot, error: KinematicError):
        if not isinstance(error, KinematicError):
            raise TypeError(f"error must be a KinematicError, got {type(error).__name__}")
        self._robot, self.kinematic_error = robot, error

    def __getattr__(self, name):
        return getattr(self._robot, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._robot.close()

    def flange_pose(self) -> np.ndarray:
        """The true ``T_base_flange`` (mm)."""
        return self.kinematic_error.flange_pose(self._robot.joints(), getattr(self._robot, "dh", UR5E))

    def tcp_pose(self) -> np.ndarray:
        """The true ``T_base_tcp`` (mm)."""
        return self.flange_pose() @ self._robot.tcp_offset()

    def reported_flange_pose(self) -> np.ndarray:
        """``T_base_flange`` as the controller reports it (the nominal table, mm)."""
        return self._robot.flange_pose()

    def move_linear(self, T_base_tcp, *args, **kwargs) -> np.ndarray:
        """The wrapped robot's move (planned through the nominal table); returns the true ``T_base_tcp``."""
        self._robot.move_linear(T_base_tcp, *args, **kwargs)
        return self.tcp_pose()


def reported_flange_pose(robot) -> np.ndarray:
    """What the robot's controller reports as its flange pose.

    Args:
        robot: a :class:`~histostudy.robot.Robot` or an :class:`InaccurateArm`.

    Returns:
        ``T_base_flange`` (4x4, mm): an InaccurateArm's nominal reading, any other robot's ``flange_pose()``.
    """
    reported = getattr(robot, "reported_flange_pose", None)
    return robot.flange_pose() if reported is None else reported()


def robot_seed(seq: np.random.SeedSequence) -> int:
    """The integer seed of the robot's repeatability noise (the controller's ``--seed``).

    Args:
        seq: the experiment's robot seed sequence.

    Returns:
        The first word of its state.
    """
    return int(seq.generate_state(1)[0])


def sim_robot(config: TargetingStudyConfig, kinematic_error: KinematicError | None = None):
    """A robot factory for :func:`~histostudy.study.targeting.experiment.run_targeting_experiment`:
    ``SimulatedUR5e`` in process, inside an :class:`InaccurateArm` when ``kinematic_error`` is given.

    Args:
        config: the study's parameters (``robot_repeatability_mm``).
        kinematic_error: a lab's arm; None: the nominal arm.

    Returns:
        ``factory(seed, initial_joints_rad)`` -> a context manager yielding the robot (closed after).
    """

    @contextlib.contextmanager
    def factory(seed: int, initial_joints_rad=HOME_JOINTS_RAD):
        robot = SimulatedUR5e(int(seed), repeatability_mm=config.robot_repeatability_mm,
                              initial_joints_rad=initial_joints_rad)
        try:
            yield robot if kinematic_error is None else InaccurateArm(robot, kinematic_error)
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
    """A robot factory: the simulated UR controller in its own process on a loopback address, driven
    by :class:`~histostudy.robot.RTDERobot` through the real ``ur_rtde`` client; its ``--seed`` is the
    experiment's robot seed, so its noise is drawn exactly as :func:`sim_robot`'s.

    Args:
        config: the study's parameters (``robot_repeatability_mm``).
        command_timeout_s: the client's timeout per command (s).

    Returns:
        ``factory(seed, initial_joints_rad)`` -> a context manager yielding the robot (the controller
        stopped after).
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
