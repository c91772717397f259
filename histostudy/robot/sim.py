""":class:`SimulatedUR5e`: an in-process UR5e behind the :class:`~histostudy.robot.base.Robot` protocol
(§II-C, repeatability +-0.03 mm), its moves planned, checked, timed and landed with noise, and faults
injected by a :class:`FaultPlan` (docs/robot.md, "The simulated arm")."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from histostudy.core import as_generator
from histostudy.geometry import check_rigid, invert_transform, rotation_angle

from .base import (
    ROTATION_ACCELERATION_RAD_S2,
    ROTATION_SPEED_RAD_S,
    ProtectiveStopError,
    RobotConnectionError,
    RobotState,
    RobotTimeout,
    UnreachablePoseError,
    Workspace,
    check_motion_parameters,
    linear_motion_time_s,
    trapezoid_fraction,
    trapezoid_time_s,
)
from .kinematics import (
    JOINT_LIMIT_RAD,
    UR5E,
    DHSpec,
    check_joints,
    forward_kinematics,
    inverse_kinematics_closest,
    linear_path_joints,
)

__all__ = ["HOME_JOINTS_RAD", "FaultPlan", "LinearPlan", "SimulatedUR5e"]

#: A start configuration with the flange pointing down in front of the base, elbow up.
HOME_JOINTS_RAD = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)


@dataclass(frozen=True)
class FaultPlan:
    """Faults to inject; moves are counted from 1 (every ``move_linear`` attempt that got planned).

    ``disconnect_after_moves``: the connection drops right after move k completes.
    ``disconnect_during_move``: the connection drops halfway (in time) through move k.
    ``protective_stop_during_move``: a protective stop halfway through move k.
    ``command_delay_s``: the controller answers every command this late (a slow controller).
    """

    disconnect_after_moves: int | None = None
    disconnect_during_move: int | None = None
    protective_stop_during_move: int | None = None
    command_delay_s: float = 0.0

    def __post_init__(self):
        for name in ("disconnect_after_moves", "disconnect_during_move", "protective_stop_during_move"):
            k = getattr(self, name)
            if k is not None and (isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1):
                raise ValueError(f"{name} must be None or an integer >= 1 (a move number), got {k!r}")
        if not (math.isfinite(self.command_delay_s) and self.command_delay_s >= 0):
            raise ValueError(f"command_delay_s must be finite and >= 0, got {self.command_delay_s!r}")


@dataclass(frozen=True)
class LinearPlan:
    """A checked linear move: the joint path, its timing, and the (noisy) final configuration.

    ``fractions`` (n,) and ``joints_rad`` (n, 6) sample the straight TCP path; the last row is the
    configuration the arm lands in (the target plus repeatability noise). ``duration_s`` follows
    the trapezoidal profile of ``profile`` = (distance, speed, acceleration) of the limiting
    component (mm or rad).
    """

    T_base_tcp_start: np.ndarray
    T_base_tcp_target: np.ndarray
    fractions: np.ndarray
    joints_rad: np.ndarray
    duration_s: float
    profile: tuple[float, float, float]
    speed_mm_s: float
    acceleration_mm_s2: float

    @property
    def q_final(self) -> np.ndarray:
        return self.joints_rad[-1]

    def fraction_at(self, t_s: float) -> float:
        """Path fraction in [0, 1] reached ``t_s`` seconds after the start."""
        distance, speed, acc = self.profile
        return trapezoid_fraction(t_s, self.duration_s, distance, speed, acc)

    def joints_at(self, t_s: float) -> np.ndarray:
        """Joint angles ``t_s`` seconds after the start (interpolated between path samples)."""
        s = self.fraction_at(t_s)
        if s >= 1.0:
            return self.joints_rad[-1].copy()
        i = int(np.searchsorted(self.fractions, s, side="right")) - 1
        i = min(max(i, 0), len(self.fractions) - 2)
        w = (s - self.fractions[i]) / (self.fractions[i + 1] - self.fractions[i])
        return (1.0 - w) * self.joints_rad[i] + w * self.joints_rad[i + 1]


def _ball_noise(rng: np.random.Generator, radius_mm: float) -> np.ndarray:
    """A displacement uniform in the ball of ``radius_mm`` (so |noise| <= repeatability always)."""
    direction = rng.standard_normal(3)
    direction /= np.linalg.norm(direction)
    return direction * radius_mm * rng.random() ** (1.0 / 3.0)


@dataclass
class _MoveLog:
    planned: int = 0
    completed: int = 0
    history: list = field(default_factory=list)


class SimulatedUR5e:
    """An in-process UR5e (§II-C) implementing the :class:`~histostudy.robot.base.Robot` protocol.

    Parameters: ``rng`` (a Generator or int seed; the repeatability noise is drawn from it, so a
    seed fixes every pose), ``repeatability_mm`` (radius of the landing noise, 0.03 mm for the
    UR5e; 0 disables it), ``initial_joints_rad``, ``T_flange_tcp`` (default identity),
    ``workspace`` (default: the 850 mm reach only), ``faults`` (:class:`FaultPlan`),
    ``command_timeout_s`` (the watchdog a client would use), ``time_scale`` (wall seconds slept per
    simulated second; 0 = instant), ``dh`` (kinematic parameters).
    """

    def __init__(
        self,
        rng,
        *,
        repeatability_mm: float = 0.03,
        initial_joints_rad=HOME_JOINTS_RAD,
        T_flange_tcp=None,
        workspace: Workspace | None = None,
        faults: FaultPlan | None = None,
        command_timeout_s: float = 10.0,
        time_scale: float = 0.0,
        dh: DHSpec = UR5E,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self._rng = as_generator(rng)
        if not (math.isfinite(repeatability_mm) and repeatability_mm >= 0):
            raise ValueError(f"repeatability_mm must be finite and >= 0, got {repeatability_mm!r}")
        if not (math.isfinite(command_timeout_s) and command_timeout_s > 0):
            raise ValueError(f"command_timeout_s must be finite and > 0, got {command_timeout_s!r}")
        if not (math.isfinite(time_scale) and time_scale >= 0):
            raise ValueError(f"time_scale must be finite and >= 0, got {time_scale!r}")
        if faults is not None and not isinstance(faults, FaultPlan):
            raise TypeError(f"faults must be a FaultPlan or None, got {type(faults).__name__}")
        if workspace is not None and not isinstance(workspace, Workspace):
            raise TypeError(f"workspace must be a Workspace or None, got {type(workspace).__name__}")
        self.repeatability_mm = float(repeatability_mm)
        self.workspace = workspace if workspace is not None else Workspace()
        self.faults = faults if faults is not None else FaultPlan()
        self.command_timeout_s = float(command_timeout_s)
        self.time_scale = float(time_scale)
        self.dh = dh
        self._sleep = sleep
        self._q = check_joints(initial_joints_rad, "initial_joints_rad").copy()
        self._T_flange_tcp = np.eye(4) if T_flange_tcp is None else check_rigid(T_flange_tcp, "T_flange_tcp").copy()
        self._connected = True
        self._protective_stop = False
        self._log = _MoveLog()
        self.sim_time_s = 0.0

    # -- connection ---------------------------------------------------------------------------
    def close(self) -> None:
        """Disconnect (idempotent); the arm stays where it is."""
        self._connected = False

    def reconnect(self) -> None:
        """Restore the connection after a drop; the arm is where the drop left it."""
        self._connected = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _require_connected(self, what: str) -> None:
        if not self._connected:
            raise RobotConnectionError(
                f"{what}: the simulated UR5e is not connected (call reconnect()); no pose is read while disconnected"
            )

    def _advance(self, seconds: float) -> None:
        self.sim_time_s += seconds
        if self.time_scale > 0 and seconds > 0:
            self._sleep(seconds * self.time_scale)

    # -- tool ---------------------------------------------------------------------------------
    def set_tcp(self, T_flange_tcp) -> None:
        """Set ``T_flange_tcp`` (mm): the TCP (transducer focal point) in the flange frame."""
        T = check_rigid(T_flange_tcp, "T_flange_tcp")
        self._require_connected("set_tcp")
        self._T_flange_tcp = T.copy()

    def tcp_offset(self) -> np.ndarray:
        """The current ``T_flange_tcp`` (mm)."""
        return self._T_flange_tcp.copy()

    # -- readings -----------------------------------------------------------------------------
    def joints(self) -> np.ndarray:
        """Joint angles in rad, shape (6,); raises RobotConnectionError when disconnected."""
        self._require_connected("joints")
        return self._q.copy()

    def flange_pose(self) -> np.ndarray:
        """``T_base_flange`` (mm) from the joints."""
        self._require_connected("flange_pose")
        return forward_kinematics(self._q, self.dh)

    def tcp_pose(self) -> np.ndarray:
        """``T_base_tcp`` (mm) = ``T_base_flange @ T_flange_tcp``."""
        self._require_connected("tcp_pose")
        return forward_kinematics(self._q, self.dh) @ self._T_flange_tcp

    def state(self) -> RobotState:
        """Connection, protective stop and motion status (never raises)."""
        return RobotState(
            connected=self._connected,
            protective_stop=self._protective_stop if self._connected else False,
            steady=self._connected,
            moves_completed=self._log.completed,
        )

    @property
    def moves_planned(self) -> int:
        """Moves planned so far (the move number of FaultPlan counts these)."""
        return self._log.planned

    # -- checks the controller exposes ---------------------------------------------------------
    def tcp_pose_for_joints(self, q_rad) -> np.ndarray:
        """``T_base_tcp`` for joints ``q_rad`` with the current TCP offset."""
        return forward_kinematics(q_rad, self.dh) @ self._T_flange_tcp

    def inverse_kinematics(self, T_base_tcp, q_near_rad=None) -> np.ndarray:
        """Joints reaching ``T_base_tcp`` with the current TCP, closest to ``q_near_rad`` (default: now)."""
        T = check_rigid(T_base_tcp, "T_base_tcp")
        q_near = self._q if q_near_rad is None else q_near_rad
        return inverse_kinematics_closest(T @ invert_transform(self._T_flange_tcp), q_near, self.dh)

    def has_inverse_kinematics(self, T_base_tcp, q_near_rad=None) -> bool:
        """Whether ``T_base_tcp`` is reachable within the joint limits."""
        try:
            self.inverse_kinematics(T_base_tcp, q_near_rad)
        except (UnreachablePoseError, ValueError):
            return False
        return True

    def is_pose_safe(self, T_base_tcp) -> bool:
        """Whether ``T_base_tcp`` lies in the workspace and is reachable (the controller's safety check)."""
        try:
            T = check_rigid(T_base_tcp, "T_base_tcp")
        except ValueError:
            return False
        if self.workspace.violation(T, T @ invert_transform(self._T_flange_tcp)) is not None:
            return False
        return self.has_inverse_kinematics(T)

    # -- motion -------------------------------------------------------------------------------
    def plan_linear(self, T_base_tcp, speed_mm_s: float, acceleration_mm_s2: float) -> LinearPlan:
        """Check and plan a linear move to ``T_base_tcp`` (mm) without executing it.

        Raises ValueError (bad pose or motion parameters), WorkspaceViolation, UnreachablePoseError,
        ProtectiveStopError or RobotConnectionError before anything moves. Draws the landing noise.
        """
        T_target = check_rigid(T_base_tcp, "T_base_tcp")
        v, a = check_motion_parameters(speed_mm_s, acceleration_mm_s2)
        self._require_connected("move_linear")
        if self._protective_stop:
            raise ProtectiveStopError("move_linear refused: the arm is in a protective stop; clear it first")
        T_tcp_flange = invert_transform(self._T_flange_tcp)
        self.workspace.check(T_target, T_target @ T_tcp_flange)
        T_start = forward_kinematics(self._q, self.dh) @ self._T_flange_tcp
        fractions, path = linear_path_joints(T_start, T_target, self._T_flange_tcp, self._q, self.dh)
        if self.repeatability_mm > 0:
            T_land = T_target.copy()
            T_land[:3, 3] += _ball_noise(self._rng, self.repeatability_mm)
            try:
                path[-1] = inverse_kinematics_closest(T_land @ T_tcp_flange, path[-1], self.dh)
            except UnreachablePoseError:
                pass  # the target sits on the reach boundary: land exactly on it
        duration = linear_motion_time_s(T_start, T_target, v, a)
        dist = float(np.linalg.norm(T_target[:3, 3] - T_start[:3, 3]))
        profile = (dist, v, a)
        if trapezoid_time_s(dist, v, a) < duration:  # rotation limits the move
            profile = (
                rotation_angle(T_start[:3, :3].T @ T_target[:3, :3]),
                ROTATION_SPEED_RAD_S,
                ROTATION_ACCELERATION_RAD_S2,
            )
        self._log.planned += 1
        return LinearPlan(T_start, T_target, fractions, path, duration, profile, v, a)

    def finish(self, plan: LinearPlan, t_s: float | None = None) -> np.ndarray:
        """Put the arm where ``plan`` has it at ``t_s`` (None: at the end, the move counts as completed)."""
        if t_s is None or t_s >= plan.duration_s:
            self._q = plan.q_final.copy()
            self._log.completed += 1
        else:
            self._q = plan.joints_at(t_s)
        return self._q.copy()

    def move_linear(self, T_base_tcp, speed_mm_s: float = 250.0, acceleration_mm_s2: float = 1200.0) -> np.ndarray:
        """Move the TCP in a straight line to ``T_base_tcp`` (mm, base frame); return the reached ``T_base_tcp``.

        ``speed_mm_s`` and ``acceleration_mm_s2`` are the tool's (as for a UR moveL). The reached
        pose differs from the target by at most ``repeatability_mm``.
        """
        f = self.faults
        if f.command_delay_s > 0:
            # The client's watchdog gives up on a controller that answers later than its timeout.
            self._require_connected("move_linear")
            if f.command_delay_s > self.command_timeout_s:
                self._advance(self.command_timeout_s)
                raise RobotTimeout(
                    f"move_linear: the controller did not answer within command_timeout_s={self.command_timeout_s} s "
                    f"(it answers after {f.command_delay_s} s); the arm did not move and is at rest"
                )
            self._advance(f.command_delay_s)
        plan = self.plan_linear(T_base_tcp, speed_mm_s, acceleration_mm_s2)
        k = self._log.planned
        if f.protective_stop_during_move == k or f.disconnect_during_move == k:
            half = 0.5 * plan.duration_s
            self._advance(half)
            self.finish(plan, half)
            if f.protective_stop_during_move == k:
                self._protective_stop = True
                raise ProtectiveStopError(
                    f"move {k}: protective stop halfway through the move; the arm stopped at "
                    f"{np.round(self.tcp_pose()[:3, 3], 3).tolist()} mm and stays stopped until cleared"
                )
            self._connected = False
            raise RobotConnectionError(
                f"move {k}: the connection dropped halfway through the move; the arm stopped there, "
                f"its pose is unknown to this client until reconnect()"
            )
        self._advance(plan.duration_s)
        self.finish(plan)
        self._log.history.append(plan)
        if f.disconnect_after_moves == k:
            self._connected = False
        return forward_kinematics(self._q, self.dh) @ self._T_flange_tcp

    def stop(self) -> None:
        """Decelerate to rest (the simulated arm is always at rest between calls)."""
        self._require_connected("stop")

    def trigger_protective_stop(self) -> None:
        """Put the arm in a protective stop (as a collision or a safety limit would)."""
        self._require_connected("trigger_protective_stop")
        self._protective_stop = True

    def clear_protective_stop(self) -> None:
        """Release a protective stop (on a real UR5e: the dashboard's 'unlock protective stop')."""
        self._require_connected("clear_protective_stop")
        self._protective_stop = False

    def move_joints(self, q_rad, speed_rad_s: float = 1.05, acceleration_rad_s2: float = 1.4) -> np.ndarray:
        """Joint-space move to ``q_rad`` (rad) with the joint speed/acceleration; returns the reached ``T_base_tcp``.

        No repeatability noise is added: joint moves serve to set start configurations.
        """
        q = check_joints(q_rad, "q_rad", JOINT_LIMIT_RAD)
        if not (math.isfinite(speed_rad_s) and speed_rad_s > 0
                and math.isfinite(acceleration_rad_s2) and acceleration_rad_s2 > 0):
            raise ValueError(f"speed_rad_s and acceleration_rad_s2 must be finite and > 0, "
                             f"got {speed_rad_s!r}, {acceleration_rad_s2!r}")
        self._require_connected("move_joints")
        if self._protective_stop:
            raise ProtectiveStopError("move_joints refused: the arm is in a protective stop; clear it first")
        T_flange = forward_kinematics(q, self.dh)
        self.workspace.check(T_flange @ self._T_flange_tcp, T_flange)
        self._advance(trapezoid_time_s(float(np.abs(q - self._q).max()), speed_rad_s, acceleration_rad_s2))
        self._q = q.copy()
        return T_flange @ self._T_flange_tcp
