"""Robot to C-arm calibration (§II-C, eq. 5-8): dual quaternions of rigid transforms, single and
batched (``dual_quaternion``); Daniilidis' AX = XB solver, eq. 8, with the dual-quaternion sign
handling near half turns (``axxb``); the calibration from flange and transducer poses, its residual
gate, and the flange pose that puts the focal point on a target (``procedure``); and, beyond the
paper, simulated poses, pose noise and the Monte-Carlo of the calibration error (``sensitivity``).
"""

from .axxb import AXXBSolution, DegenerateMotionError, daniilidis_matrix, solve_axxb, solve_axxb_dual_quaternions
from .dual_quaternion import dual_quaternion_from_transform, transform_from_dual_quaternion
from .procedure import CalibrationError, HandEyeCalibration, calibrate, flange_pose_for_target, motion_pairs
from .sensitivity import R_BASE_FLANGE_DOWN, calibration_sensitivity, perturb_pose, simulate_poses

__all__ = [
    "AXXBSolution",
    "CalibrationError",
    "DegenerateMotionError",
    "HandEyeCalibration",
    "R_BASE_FLANGE_DOWN",
    "calibrate",
    "calibration_sensitivity",
    "daniilidis_matrix",
    "dual_quaternion_from_transform",
    "flange_pose_for_target",
    "motion_pairs",
    "perturb_pose",
    "simulate_poses",
    "solve_axxb",
    "solve_axxb_dual_quaternions",
    "transform_from_dual_quaternion",
]
