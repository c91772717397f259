"""The UR5e that carries the transducer (§II-C), simulated (:class:`SimulatedUR5e`) or real
(:class:`RTDERobot`), behind one :class:`Robot` protocol in millimetres, radians and 4x4 transforms
``T_<to>_<from>`` in the robot base frame; its errors derive from :class:`RobotError`. Modules:
``base``, ``kinematics``, ``sim``, ``units``; sub-packages ``rtde`` and ``controller`` (the simulated
UR controller, ``python -m histostudy.robot.controller``). See docs/robot.md.
"""

from .base import (
    ProtectiveStopError,
    Robot,
    RobotConnectionError,
    RobotError,
    RobotTimeout,
    UnreachablePoseError,
    Workspace,
    WorkspaceViolation,
)
from .kinematics import UR5E, forward_kinematics, inverse_kinematics_closest
from .rtde import RTDERobot
from .sim import HOME_JOINTS_RAD, SimulatedUR5e
from .units import pose_from_transform, transform_from_pose

__all__ = [
    "HOME_JOINTS_RAD",
    "UR5E",
    "ProtectiveStopError",
    "RTDERobot",
    "Robot",
    "RobotConnectionError",
    "RobotError",
    "RobotTimeout",
    "SimulatedUR5e",
    "UnreachablePoseError",
    "Workspace",
    "WorkspaceViolation",
    "forward_kinematics",
    "inverse_kinematics_closest",
    "pose_from_transform",
    "transform_from_pose",
]
