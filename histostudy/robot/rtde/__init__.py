"""A real UR5e, or the simulated controller, through ur_rtde, behind the :class:`~histostudy.robot.base.Robot`
protocol (§II-C): the robot (``_robot``) over a connection whose calls run under watchdogs
(``_connection``); the unit conversions it uses are :mod:`histostudy.robot.units`."""

from ._robot import RTDERobot

__all__ = ["RTDERobot"]
