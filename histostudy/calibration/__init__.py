"""Robot to C-arm calibration (§II-C, eq. 6-8): Daniilidis' dual-quaternion solution of AX = XB, the
calibration procedure that moves the robot and estimates the transducer in each pose, and the
calibration's sensitivity to pose noise (``handeye``).
"""

from .handeye import (AXXBSolution, CalibrationError, DegenerateMotionError, HandEyeCalibration, R_BASE_FLANGE_DOWN,
                      calibrate, calibration_sensitivity, daniilidis_matrix, dual_quaternion_from_transform,
                      flange_pose_for_target, motion_pairs, perturb_pose, simulate_poses, solve_axxb,
                      solve_axxb_dual_quaternions, transform_from_dual_quaternion)

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
