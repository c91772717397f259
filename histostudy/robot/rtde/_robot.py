""":class:`RTDERobot`: a real UR5e, or the simulated controller, through ur_rtde behind the
:class:`~histostudy.robot.base.Robot` protocol (§II-C); mm and 4x4 transforms here, metres and
axis-angle converted by :mod:`histostudy.robot.units` (docs/robot.md, "The RTDE client")."""

from __future__ import annotations

import math
import time

import numpy as np

from histostudy.geometry import check_rigid, invert_transform, rotation_angle

from ..base import (
    ProtectiveStopError,
    RobotError,
    RobotState,
    RobotTimeout,
    UnreachablePoseError,
    Workspace,
    WorkspaceViolation,
    check_motion_parameters,
    linear_motion_time_s,
)
from ..kinematics import UR5E, DHSpec, forward_kinematics, inverse_kinematics_closest, linear_path_joints
from ..units import pose_from_transform, transform_from_pose
from ._connection import DASHBOARD_PORT, RTDEConnection, probe_port

__all__ = ["RTDERobot", "UR_RTDE_VERSION"]

#: The ur_rtde version whose register protocol the simulated controller implements.
UR_RTDE_VERSION = "1.6.5"

#: Below these TCP speeds (m/s, rad/s: ur_rtde's units) the arm counts as at rest; a real
#: controller's readings jitter well below them.
REST_SPEED_M_S = 1e-3
REST_SPEED_RAD_S = 1e-2


def _at_rest(speed) -> bool:
    speed = np.asarray(speed, dtype=float)
    return bool(np.linalg.norm(speed[:3]) < REST_SPEED_M_S and np.linalg.norm(speed[3:]) < REST_SPEED_RAD_S)


class RTDERobot(RTDEConnection):
    """A UR5e driven through ``ur_rtde`` (§II-C), implementing :class:`~histostudy.robot.base.Robot`.

    Parameters: ``host`` (the controller's IP, or a loopback address of the simulated
    controller), ``workspace`` (checked before every move; default: the 850 mm reach),
    ``command_timeout_s`` (watchdog of every non-motion call), ``move_timeout_margin_s`` (added to
    twice the expected motion time for a move's watchdog), ``connect_timeout_s`` (port probe),
    ``settle_timeout_s``/``settle_tolerance_mm``/``settle_tolerance_rad`` (waiting for the received
    pose to converge after a move), ``frequency_hz`` (RTDE frequency, -1: the client's default),
    ``connect`` (connect now).
    """

    def __init__(
        self,
        host: str,
        *,
        workspace: Workspace | None = None,
        command_timeout_s: float = 5.0,
        move_timeout_margin_s: float = 5.0,
        connect_timeout_s: float = 2.0,
        settle_timeout_s: float = 2.0,
        settle_tolerance_mm: float = 0.5,
        settle_tolerance_rad: float = 1e-3,
        frequency_hz: float = -1.0,
        dh: DHSpec = UR5E,
        connect: bool = True,
    ):
        if not isinstance(host, str) or not host:
            raise ValueError(f"host must be a non-empty IP address or host name, got {host!r}")
        for name, value in (
            ("command_timeout_s", command_timeout_s),
            ("move_timeout_margin_s", move_timeout_margin_s),
            ("connect_timeout_s", connect_timeout_s),
            ("settle_timeout_s", settle_timeout_s),
            ("settle_tolerance_mm", settle_tolerance_mm),
            ("settle_tolerance_rad", settle_tolerance_rad),
        ):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if workspace is not None and not isinstance(workspace, Workspace):
            raise TypeError(f"workspace must be a Workspace or None, got {type(workspace).__name__}")
        super().__init__(host, command_timeout_s=command_timeout_s, connect_timeout_s=connect_timeout_s,
                         settle_timeout_s=settle_timeout_s, frequency_hz=frequency_hz)
        self.workspace = workspace if workspace is not None else Workspace()
        self.move_timeout_margin_s = float(move_timeout_margin_s)
        self.settle_tolerance_mm = float(settle_tolerance_mm)
        self.settle_tolerance_rad = float(settle_tolerance_rad)
        self.dh = dh
        self._T_flange_tcp = np.eye(4)
        self._moves_completed = 0
        if connect:
            self.connect()

    def connect(self) -> None:
        """Open the receive and control interfaces (the control script is uploaded by ur_rtde)."""
        if self._control is not None:
            return
        super().connect()
        # The controller keeps its TCP across client sessions; ours is the one we last set.
        self.set_tcp(self._T_flange_tcp)

    # -- tool ---------------------------------------------------------------------------------
    def set_tcp(self, T_flange_tcp) -> None:
        """Set ``T_flange_tcp`` (mm) on the controller: the transducer focal point in the flange frame."""
        T = check_rigid(T_flange_tcp, "T_flange_tcp")
        self._require_connected("set_tcp")
        self._check_not_stopped("set_tcp")
        ok = self._call("setTcp", self._control.setTcp, pose_from_transform(T), timeout_s=self.command_timeout_s)
        if not ok:
            self._explain_false("setTcp")
        self._T_flange_tcp = T.copy()
        # The receive interface can still hold packets computed with the old TCP.
        self._wait_fresh_data("set_tcp")

    def tcp_offset(self) -> np.ndarray:
        """The ``T_flange_tcp`` last set (mm)."""
        return self._T_flange_tcp.copy()

    # -- readings -----------------------------------------------------------------------------
    def _read(self, what: str, getter) -> list:
        self._require_connected(what)
        value = list(getter())
        # The client keeps returning the last value after a drop: re-check after reading.
        self._require_connected(what)
        if len(value) != 6 or not all(math.isfinite(v) for v in value):
            raise RobotError(f"{what}: the controller sent an invalid value {value!r}")
        return value

    def joints(self) -> np.ndarray:
        """Measured joint angles (rad, (6,)); raises RobotConnectionError when not connected."""
        return np.array(self._read("joints", lambda: self._receive.getActualQ()))

    def tcp_pose(self) -> np.ndarray:
        """Measured ``T_base_tcp`` (mm) as reported by the controller."""
        return transform_from_pose(self._read("tcp_pose", lambda: self._receive.getActualTCPPose()), "actual TCP pose")

    def flange_pose(self) -> np.ndarray:
        """``T_base_flange`` (mm): forward kinematics of the measured joints, computed locally."""
        return forward_kinematics(self.joints(), self.dh)

    def state(self) -> RobotState:
        """Connection, protective stop and motion status; never raises for a lost connection."""
        if not self._is_connected():
            return RobotState(False, False, False, self._moves_completed)
        try:
            pstop = bool(self._receive.isProtectiveStopped())
            speed = np.asarray(self._receive.getActualTCPSpeed(), dtype=float)
        except RuntimeError:
            return RobotState(False, False, False, self._moves_completed)
        connected = self._is_connected()
        steady = connected and _at_rest(speed)
        return RobotState(connected, pstop and connected, steady, self._moves_completed)

    # -- checks -------------------------------------------------------------------------------
    def _check_not_stopped(self, what: str) -> None:
        if self._receive.isProtectiveStopped():
            raise ProtectiveStopError(
                f"{what} refused: the arm at {self.host} is in a protective stop; clear it "
                f"(clear_protective_stop() or the teach pendant) first"
            )

    def _explain_false(self, what: str):
        self._require_connected(what)
        self._wait_fresh_data(what)  # the reason (a protective stop) may not have arrived yet
        if self._receive.isProtectiveStopped():
            # Where it stopped, whichever of the command's answer or the stop reached us first.
            where = np.round(self.tcp_pose()[:3, 3], 3).tolist()
            raise ProtectiveStopError(f"{what} failed: the arm at {self.host} is in a protective stop; it stopped at "
                                      f"{where} mm and stays stopped until cleared")
        raise RobotError(f"{what} returned False: the controller at {self.host} did not execute it")

    def check_pose(self, T_base_tcp) -> np.ndarray:
        """All checks made before a move; returns the joints the local IK expects. Raises on any failure.

        Order: finite and rigid (ValueError), the configured workspace (WorkspaceViolation), the
        local inverse kinematics (UnreachablePoseError), the controller's safety limits
        (``isPoseWithinSafetyLimits``, WorkspaceViolation) and its inverse kinematics
        (``getInverseKinematicsHasSolution``, UnreachablePoseError).
        """
        T = check_rigid(T_base_tcp, "T_base_tcp")
        T_flange = T @ invert_transform(self._T_flange_tcp)
        self.workspace.check(T, T_flange)
        q_now = self.joints()
        q = inverse_kinematics_closest(T_flange, q_now, self.dh)
        pose = pose_from_transform(T)
        if not self._call("isPoseWithinSafetyLimits", self._control.isPoseWithinSafetyLimits, pose,
                          timeout_s=self.command_timeout_s):
            # False also comes back when the link is being lost: believe it only on fresh data.
            self._wait_fresh_data("isPoseWithinSafetyLimits")
            self._check_not_stopped("isPoseWithinSafetyLimits")
            raise WorkspaceViolation(f"the controller at {self.host} reports the pose {pose} outside its safety limits")
        if not self._call("getInverseKinematicsHasSolution", self._control.getInverseKinematicsHasSolution, pose,
                          list(q_now), timeout_s=self.command_timeout_s):
            self._wait_fresh_data("getInverseKinematicsHasSolution")
            self._check_not_stopped("getInverseKinematicsHasSolution")
            raise UnreachablePoseError(f"the controller at {self.host} finds no inverse kinematics for {pose}")
        return q

    # -- motion -------------------------------------------------------------------------------
    def move_linear(self, T_base_tcp, speed_mm_s: float = 250.0, acceleration_mm_s2: float = 1200.0) -> np.ndarray:
        """Linear move of the TCP to ``T_base_tcp`` (mm, base frame); returns the settled ``T_base_tcp``.

        Checks the pose first (:meth:`check_pose`) and the straight path for joint limits and
        singularities (:func:`~histostudy.robot.kinematics.linear_path_joints`), runs ``moveL`` under a
        watchdog of twice the
        expected motion time plus ``move_timeout_margin_s``, then waits until the received pose is
        steady and within the settle tolerances of the target.
        """
        T = check_rigid(T_base_tcp, "T_base_tcp")
        v, a = check_motion_parameters(speed_mm_s, acceleration_mm_s2)
        self._require_connected("move_linear")
        self._check_not_stopped("move_linear")
        self.check_pose(T)
        # The straight path too: a singularity on the way would end in a protective stop.
        T_now = self.tcp_pose()
        linear_path_joints(T_now, T, self._T_flange_tcp, self.joints(), self.dh)
        expected = linear_motion_time_s(T_now, T, v, a)
        ok = self._call(
            "moveL",
            self._control.moveL,
            pose_from_transform(T),
            v / 1000.0,
            a / 1000.0,
            timeout_s=2.0 * expected + self.move_timeout_margin_s,
        )
        if not ok:
            self._explain_false("moveL")
        reached = self._settle(T)
        self._moves_completed += 1
        return reached

    def _settle(self, T_target: np.ndarray) -> np.ndarray:
        """Wait (bounded) until the received pose is at rest near the target; return it.

        "Caught up" means two packets from the controller (distinct timestamps) that both show the
        arm at rest within the settle tolerances of the target and within 0.01 mm of each other:
        a real controller's readings jitter slightly, so exact equality is not required.
        """
        t0 = time.monotonic()
        last = None
        while True:
            stamp = self._receive.getTimestamp()
            T = self.tcp_pose()
            speed = np.asarray(self._receive.getActualTCPSpeed(), dtype=float)
            if self._receive.isProtectiveStopped():
                self._require_connected("move_linear")
                raise ProtectiveStopError(
                    f"moveL: the arm at {self.host} entered a protective stop during the move and stopped at "
                    f"{np.round(T[:3, 3], 3).tolist()} mm; it stays stopped until cleared"
                )
            settled = (
                _at_rest(speed)
                and np.linalg.norm(T[:3, 3] - T_target[:3, 3]) <= self.settle_tolerance_mm
                and rotation_angle(T[:3, :3].T @ T_target[:3, :3]) <= self.settle_tolerance_rad
            )
            if settled:
                if last is not None and stamp > last[0] and np.abs(T[:3, 3] - last[1][:3, 3]).max() < 0.01:
                    return T
                if last is None or stamp > last[0]:
                    last = (stamp, T)
            else:
                last = None
            if time.monotonic() - t0 > self.settle_timeout_s:
                self._require_connected("move_linear")
                raise RobotTimeout(
                    f"moveL: the received pose at {self.host} did not settle within {self.settle_tolerance_mm} mm "
                    f"of the target in {self.settle_timeout_s} s (last position {np.round(T[:3, 3], 3).tolist()} mm)"
                )
            time.sleep(0.001)

    def stop(self, deceleration_mm_s2: float = 2000.0) -> None:
        """Decelerate the arm to rest (``stopL``)."""
        if not (math.isfinite(deceleration_mm_s2) and deceleration_mm_s2 > 0):
            raise ValueError(f"deceleration_mm_s2 must be finite and > 0, got {deceleration_mm_s2!r}")
        self._require_connected("stop")
        self._call("stopL", self._control.stopL, deceleration_mm_s2 / 1000.0, timeout_s=self.command_timeout_s)
        self._wait_fresh_data("stop")

    def trigger_protective_stop(self) -> None:
        """Put the arm in a protective stop (``triggerProtectiveStop``)."""
        self._require_connected("trigger_protective_stop")
        self._call("triggerProtectiveStop", self._control.triggerProtectiveStop, timeout_s=self.command_timeout_s)
        self._wait_fresh_data("trigger_protective_stop")

    def clear_protective_stop(self) -> None:
        """Unlock a protective stop through the dashboard server, then reconnect (re-uploading the script)."""
        import dashboard_client

        self._require_connected("clear_protective_stop")
        probe_port(self.host, DASHBOARD_PORT, self.connect_timeout_s)
        dash = dashboard_client.DashboardClient(self.host)
        try:
            self._call("dashboard connect", dash.connect, timeout_s=self.command_timeout_s)
            self._call("closeSafetyPopup", dash.closeSafetyPopup, timeout_s=self.command_timeout_s)
            self._call("unlockProtectiveStop", dash.unlockProtectiveStop, timeout_s=self.command_timeout_s)
        finally:
            try:
                dash.disconnect()
            except RuntimeError:
                pass
        self.reconnect()
