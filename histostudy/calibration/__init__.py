"""Robot to C-arm hand-eye calibration (§II-C, eq. 5-8): :func:`calibrate` solves AX = XB
(Daniilidis, ``axxb``) on flange and transducer poses into a :class:`HandEyeCalibration`; beyond
the paper, the Monte-Carlo of its error (``sensitivity``) and the chain run to a target with the
transducer's half-turn symmetry resolved (``targeting``).
"""

from .axxb import DegenerateMotionError
from .procedure import CalibrationError, HandEyeCalibration, calibrate
from .sensitivity import R_BASE_FLANGE_DOWN, calibration_sensitivity, perturb_pose
from .targeting import DOWN, HALF_TURN, calibrate_half_turns, target_orientation, tcp_for_target

__all__ = [
    "calibrate",
    "HandEyeCalibration",
    "CalibrationError",
    "DegenerateMotionError",
    "calibration_sensitivity",
    "perturb_pose",
    "R_BASE_FLANGE_DOWN",
    "calibrate_half_turns",
    "target_orientation",
    "tcp_for_target",
    "DOWN",
    "HALF_TURN",
]
