"""The :class:`Robot` protocol, its errors, the safety workspace and the motion-time model (§II-C), in mm,
rad and 4x4 rigid transforms ``T_<to>_<from>`` (``T_base_tcp = T_base_flange @ T_flange_tcp``; the TCP is
the transducer's focal point). See docs/robot.md."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from histostudy.geometry import check_rigid, rotation_angle

__all__ = [
    "MAX_ACCELERATION_MM_S2",
    "MAX_SPEED_MM_S",
    "REACH_MM",
    "ProtectiveStopError",
    "Robot",
    "RobotConnectionError",
    "RobotError",
    "RobotState",
    "RobotTimeout",
    "UnreachablePoseError",
    "Workspace",
    "WorkspaceViolation",
    "check_motion_parameters",
    "linear_motion_time_s",
    "trapezoid_time_s",
]

#: ur_rtde accepts moveL speeds in [0; 3] m/s and accelerations in [0; 150] m/s^2 (it raises
#: ValueError outside); the same bounds, in mm, apply to both robots so that a sequence valid for
#: the simulation is valid for the real arm.
MAX_SPEED_MM_S = 3000.0
#: The UR5e's specified reach in mm (the default Workspace reach).
REACH_MM = 850.0
MAX_ACCELERATION_MM_S2 = 150000.0

#: The motion-time model's tool-rotation limits, an assumption of this model: a UR moveL limits
#: the translation by its speed/acceleration arguments; these bound rotation-dominated moves.
ROTATION_SPEED_RAD_S = 1.0472
ROTATION_ACCELERATION_RAD_S2 = 6.0


class RobotError(RuntimeError):
    """Base class of every robot failure; the message says what failed and what state the arm is in."""


class RobotConnectionError(RobotError):
    """The controller cannot be reached, or the connection dropped; no pose is read as valid."""


class ProtectiveStopError(RobotError):
    """The arm is in a protective stop: it does not move until the stop is cleared."""


class UnreachablePoseError(RobotError):
    """No joint solution within the joint limits reaches the pose, or the straight path leaves them."""


class WorkspaceViolation(RobotError):
    """The pose lies outside the configured safety workspace or the controller's safety limits."""


class RobotTimeout(RobotError, TimeoutError):
    """A command did not complete within its watchdog time; the arm's state is unknown until reconnected."""


@dataclass(frozen=True)
class RobotState:
    """Snapshot of a robot's status.

    ``connected``: the controller answers and the data is live. ``protective_stop``: the arm is in
    a protective stop (False when not connected: unknown). ``steady``: the arm is not moving
    (False when not connected: unknown). ``moves_completed``: linear moves finished since
    construction.
    """

    connected: bool
    protective_stop: bool
    steady: bool
    moves_completed: int


@dataclass(frozen=True)
class Workspace:
    """Safety workspace in the robot base frame, checked before every move by both robots (§II-C).

    A pose is accepted when its TCP position lies inside the box (if given) and inside the sphere (if
    given), and its flange lies within ``reach_mm`` of the shoulder.

    Args:
        lower_mm: the box's lower corner ``(x, y, z)``, mm, base frame; given with ``upper_mm``.
        upper_mm: its upper corner, above ``lower_mm`` on every axis.
        center_mm: the sphere's centre, mm, base frame; given with ``radius_mm``.
        radius_mm: its radius, mm, > 0.
        reach_mm: the arm's reach from the shoulder, mm (the UR5e's 850 mm).
        shoulder_mm: the shoulder joint's position in the base frame, mm.

    Raises:
        ValueError: a corner or centre not 3 finite numbers, a pair given alone, a box inverted, or a
            radius or reach not finite and > 0.
    """

    lower_mm: tuple[float, float, float] | None = None
    upper_mm: tuple[float, float, float] | None = None
    center_mm: tuple[float, float, float] | None = None
    radius_mm: float | None = None
    reach_mm: float = REACH_MM
    shoulder_mm: tuple[float, float, float] = (0.0, 0.0, 162.5)

    def __post_init__(self):
        if (self.lower_mm is None) != (self.upper_mm is None):
            raise ValueError(
                f"lower_mm and upper_mm must be given together, got lower_mm={self.lower_mm!r}, "
                f"upper_mm={self.upper_mm!r}"
            )
        for name in ("lower_mm", "upper_mm", "center_mm", "shoulder_mm"):
            value = getattr(self, name)
            if value is not None:
                arr = np.asarray(value, dtype=np.float64)
                if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                    raise ValueError(f"{name} must be 3 finite numbers in mm, got {value!r}")
                object.__setattr__(self, name, tuple(float(v) for v in arr))
        if self.lower_mm is not None and not np.all(np.less(self.lower_mm, self.upper_mm)):
            raise ValueError(
                f"lower_mm must be below upper_mm on every axis, got lower_mm={self.lower_mm}, "
                f"upper_mm={self.upper_mm}"
            )
        if (self.center_mm is None) != (self.radius_mm is None):
            raise ValueError(
                f"center_mm and radius_mm must be given together, got center_mm={self.center_mm!r}, "
                f"radius_mm={self.radius_mm!r}"
            )
        if self.radius_mm is not None and not (math.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise ValueError(f"radius_mm must be finite and > 0, got {self.radius_mm!r}")
        if not (math.isfinite(self.reach_mm) and self.reach_mm > 0):
            raise ValueError(f"reach_mm must be finite and > 0, got {self.reach_mm!r}")

    def violation(self, T_base_tcp, T_base_flange) -> str | None:
        """Why the pose is outside the workspace, or None when it is inside. Both in the base frame, mm."""
        p_tcp = np.asarray(T_base_tcp, dtype=np.float64)[:3, 3]
        p_flange = np.asarray(T_base_flange, dtype=np.float64)[:3, 3]
        if self.lower_mm is not None and self.upper_mm is not None:  # given together (checked above)
            lo, hi = np.asarray(self.lower_mm), np.asarray(self.upper_mm)
            if np.any(p_tcp < lo) or np.any(p_tcp > hi):
                return (
                    f"TCP position {np.round(p_tcp, 3).tolist()} mm lies outside the workspace box "
                    f"lower_mm={list(self.lower_mm)}, upper_mm={list(self.upper_mm)}"
                )
        if self.center_mm is not None and self.radius_mm is not None:  # given together (checked above)
            dist = float(np.linalg.norm(p_tcp - np.asarray(self.center_mm)))
            if dist > self.radius_mm:
                return (
                    f"TCP position {np.round(p_tcp, 3).tolist()} mm lies {dist:.3f} mm from the workspace "
                    f"sphere centre {list(self.center_mm)}, beyond radius_mm={self.radius_mm}"
                )
        reach = float(np.linalg.norm(p_flange - np.asarray(self.shoulder_mm)))
        if reach > self.reach_mm:
            return (
                f"flange position {np.round(p_flange, 3).tolist()} mm lies {reach:.3f} mm from the "
                f"shoulder, beyond reach_mm={self.reach_mm}"
            )
        return None

    def check(self, T_base_tcp, T_base_flange) -> None:
        """Raise :class:`WorkspaceViolation` when :meth:`violation` finds the pose outside."""
        why = self.violation(T_base_tcp, T_base_flange)
        if why is not None:
            raise WorkspaceViolation(f"pose rejected before moving: {why}")


def check_motion_parameters(speed_mm_s, acceleration_mm_s2) -> tuple[float, float]:
    """Validate a linear move's tool speed (mm/s) and acceleration (mm/s^2); returns them as floats.

    Bounds are those ur_rtde enforces for moveL (0 < speed <= 3000 mm/s, 0 < acceleration
    <= 150000 mm/s^2); zero is rejected too because a move at zero speed never ends.
    """
    v = float(speed_mm_s)
    a = float(acceleration_mm_s2)
    if not (math.isfinite(v) and 0.0 < v <= MAX_SPEED_MM_S):
        raise ValueError(f"speed_mm_s must be in (0, {MAX_SPEED_MM_S:g}] mm/s, got {speed_mm_s!r}")
    if not (math.isfinite(a) and 0.0 < a <= MAX_ACCELERATION_MM_S2):
        raise ValueError(
            f"acceleration_mm_s2 must be in (0, {MAX_ACCELERATION_MM_S2:g}] mm/s^2, got {acceleration_mm_s2!r}"
        )
    return v, a


def trapezoid_time_s(distance: float, speed: float, acceleration: float) -> float:
    """Duration of a rest-to-rest trapezoidal (or triangular) velocity profile over ``distance``."""
    distance = abs(float(distance))
    if distance == 0.0:
        return 0.0
    if distance >= speed * speed / acceleration:
        return distance / speed + speed / acceleration
    return 2.0 * math.sqrt(distance / acceleration)


def trapezoid_fraction(t_s: float, duration_s: float, distance: float, speed: float, acceleration: float) -> float:
    """Fraction in [0, 1] of the path covered at time ``t_s`` of a trapezoidal profile of ``duration_s``."""
    if duration_s <= 0.0 or distance <= 0.0 or t_s >= duration_s:
        return 1.0
    if t_s <= 0.0:
        return 0.0
    # The profile actually used: peak speed limited by the distance (triangular when short).
    v = min(speed, math.sqrt(distance * acceleration))
    t_acc = v / acceleration
    if t_s < t_acc:
        s = 0.5 * acceleration * t_s * t_s
    elif t_s < duration_s - t_acc:
        s = 0.5 * v * t_acc + v * (t_s - t_acc)
    else:
        rest = duration_s - t_s
        s = distance - 0.5 * acceleration * rest * rest
    return min(max(s / distance, 0.0), 1.0)


def linear_motion_time_s(T_start, T_end, speed_mm_s: float, acceleration_mm_s2: float) -> float:
    """Duration in s of a moveL from ``T_start`` to ``T_end`` (TCP poses, mm).

    The slower of the translation (tool speed/acceleration) and the rotation (the module's
    ROTATION_* limits) sets the time, as on the UR controller, where both finish together.
    """
    v, a = check_motion_parameters(speed_mm_s, acceleration_mm_s2)
    T0 = check_rigid(T_start, "T_start")
    T1 = check_rigid(T_end, "T_end")
    dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
    angle = rotation_angle(T0[:3, :3].T @ T1[:3, :3])
    return max(
        trapezoid_time_s(dist, v, a),
        trapezoid_time_s(angle, ROTATION_SPEED_RAD_S, ROTATION_ACCELERATION_RAD_S2),
    )


@runtime_checkable
class Robot(Protocol):
    """What the calibration and targeting code (§II-C, §II-D) needs from an arm.

    Implemented by :class:`~histostudy.robot.sim.SimulatedUR5e` (in process) and
    :class:`~histostudy.robot.rtde._robot.RTDERobot` (a real UR5e, or the simulated controller, through
    ur_rtde). Poses are 4x4 transforms in mm in the robot base frame; joints in rad.
    """

    def set_tcp(self, T_flange_tcp) -> None:
        """Set the tool centre point (the transducer focal point) in the flange frame."""

    def tcp_offset(self) -> np.ndarray:
        """The current ``T_flange_tcp``."""

    def move_linear(self, T_base_tcp, speed_mm_s: float = 250.0, acceleration_mm_s2: float = 1200.0) -> np.ndarray:
        """Move the TCP along a straight line to ``T_base_tcp``; return the reached ``T_base_tcp``."""

    def tcp_pose(self) -> np.ndarray:
        """The measured ``T_base_tcp``; raises :class:`RobotConnectionError` when not connected."""

    def flange_pose(self) -> np.ndarray:
        """The measured ``T_base_flange`` (forward kinematics of the joints)."""

    def joints(self) -> np.ndarray:
        """The measured joint angles, rad, shape (6,)."""

    def stop(self) -> None:
        """Decelerate to rest."""

    def state(self) -> RobotState:
        """Connection, protective-stop and motion status (never raises for a lost connection)."""

    def close(self) -> None:
        """Release the connection (idempotent)."""
