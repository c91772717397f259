"""A simulated UR controller on loopback that the unmodified ``ur_rtde`` client drives (§II-C robot
layer): the child process and its command line (``_process``, ``python -m
histostudy.robot.controller``), the simulated arm (``_arm``), the URScript subset it runs
(``_program``), the RTDE wire protocol (``_protocol``) and the server (``_server``).
"""

from . import _arm, _process, _program, _protocol, _server
from ._arm import ControllerArm, MotionInProgress
from ._process import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT, Command, ControllerProcess, SimulatedController, main
from ._program import ControlProgram
from ._protocol import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT, Command, RTDERecipe, field_type
from ._server import SimulatedController

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_arm.__all__, *_process.__all__, *_program.__all__, *_protocol.__all__, *_server.__all__]))
