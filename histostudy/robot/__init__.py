"""The robot layer: the UR5e that carries the transducer (§II-C), simulated or real, behind one protocol.

Entry points::

    from histostudy.robot import SimulatedUR5e, RTDERobot
    # the simulated UR controller that the real ur_rtde client drives over loopback:
    #   python -m histostudy.robot.controller --host 127.0.0.1

The :class:`Robot` protocol (``base.py``), in millimetres, radians and 4x4 transforms
``T_<to>_<from>`` in the robot base frame:

- ``set_tcp(T_flange_tcp)`` / ``tcp_offset()``: the tool centre point (the transducer's focal
  point) in the flange frame, so that a linear move aims the focal point;
- ``move_linear(T_base_tcp, speed_mm_s=250, acceleration_mm_s2=1200)`` -> the reached
  ``T_base_tcp``; every pose is checked (finite, rigid, inside the :class:`Workspace`, reachable)
  before anything moves;
- ``tcp_pose()`` / ``flange_pose()`` -> ``T_base_tcp`` / ``T_base_flange``; ``joints()`` -> rad (6,);
  these raise :class:`RobotConnectionError` rather than return a stale pose;
- ``stop()``, ``state()`` -> :class:`RobotState` (connected, protective_stop, steady,
  moves_completed), ``close()``.

Errors, all subclasses of :class:`RobotError`: :class:`RobotConnectionError` (unreachable
controller or dropped connection), :class:`ProtectiveStopError`, :class:`UnreachablePoseError`
(no IK within the +-360 deg joint limits, or the straight path crosses a singularity),
:class:`WorkspaceViolation` (outside the configured workspace or the controller's safety limits),
:class:`RobotTimeout` (a watchdog expired; also a ``TimeoutError``). Invalid arguments (a
non-rigid or non-finite pose, a speed outside (0, 3000] mm/s) raise ``ValueError``.

Modules: ``base`` (protocol, errors, Workspace, motion-time model), ``kinematics`` (UR5e DH
forward and analytic inverse kinematics), ``sim`` (:class:`SimulatedUR5e`, :class:`FaultPlan`),
the sub-package ``rtde`` (:class:`RTDERobot`, ur_rtde's interfaces under watchdogs, the
metre/axis-angle boundary :func:`pose_from_transform`, :func:`transform_from_pose`). The simulated
UR controller, not imported here: the sub-package ``controller`` (its command line and
:class:`~histostudy.robot.controller.ControllerProcess`, the dashboard, RTDE and script servers, the
register handshake and commands, the arm's moves in wall-clock time with injected faults, and the
ports, command numbers, RTDE recipes and framing).
"""

from .base import (
                   ProtectiveStopError,
                   Robot,
                   RobotConnectionError,
                   RobotError,
                   RobotState,
                   RobotTimeout,
                   UnreachablePoseError,
                   Workspace,
                   WorkspaceViolation,
)
from .kinematics import UR5E, forward_kinematics, inverse_kinematics, inverse_kinematics_closest
from .rtde import RTDERobot, pose_from_transform, transform_from_pose
from .sim import HOME_JOINTS_RAD, FaultPlan, SimulatedUR5e

__all__ = [
    "HOME_JOINTS_RAD",
    "UR5E",
    "FaultPlan",
    "ProtectiveStopError",
    "RTDERobot",
    "Robot",
    "RobotConnectionError",
    "RobotError",
    "RobotState",
    "RobotTimeout",
    "SimulatedUR5e",
    "UnreachablePoseError",
    "Workspace",
    "WorkspaceViolation",
    "forward_kinematics",
    "inverse_kinematics",
    "inverse_kinematics_closest",
    "pose_from_transform",
    "transform_from_pose",
]
