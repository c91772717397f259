"""Deprecated path: ``histostudy.handeye`` moved to :mod:`histostudy.calibration` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.calibration import (AXXBSolution, CalibrationError, DegenerateMotionError, HandEyeCalibration,
                                    calibrate, calibration_sensitivity, daniilidis_matrix,
                                    dual_quaternion_from_transform, flange_pose_for_target, motion_pairs,
                                    perturb_pose, simulate_poses, solve_axxb, solve_axxb_dual_quaternions,
                                    transform_from_dual_quaternion)

__all__ = ["AXXBSolution", "CalibrationError", "DegenerateMotionError", "HandEyeCalibration", "calibrate", "calibration_sensitivity", "daniilidis_matrix", "dual_quaternion_from_transform", "flange_pose_for_target", "motion_pairs", "perturb_pose", "simulate_poses", "solve_axxb", "solve_axxb_dual_quaternions", "transform_from_dual_quaternion"]

warnings.warn("histostudy.handeye is deprecated: import from histostudy.calibration instead", DeprecationWarning, stacklevel=2)
