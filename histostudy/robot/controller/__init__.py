"""A simulated UR controller on loopback that the unmodified ur_rtde client drives (§II-C): the child
process and its command line (``_process``; ``python -m histostudy.robot.controller``), the server
(``_server``), the URScript subset it runs (``_program``), the simulated arm (``_arm``) and the RTDE
wire protocol (``_protocol``)."""

from ._process import ControllerProcess, main

__all__ = ["ControllerProcess", "main"]
