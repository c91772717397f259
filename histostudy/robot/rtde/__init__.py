"""A real UR5e (or the simulated controller) through ``ur_rtde``, behind the ``Robot`` protocol
(§II-C): the robot (``_robot``), the checked connection (``_connection``) and the unit
conversions between the library's millimetres and ur_rtde's metres (``_units``).
"""

from . import _connection, _robot, _units
from ._connection import RTDEConnection
from ._robot import UR_RTDE_VERSION, RTDERobot
from ._units import pose_from_transform, transform_from_pose

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_connection.__all__, *_robot.__all__, *_units.__all__]))
