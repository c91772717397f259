"""Robot to C-arm calibration (§II-C, eq. 5-8): dual quaternions of rigid transforms, single and
batched (``dual_quaternion``); Daniilidis' AX = XB solver, eq. 8, with the dual-quaternion sign
handling near half turns (``axxb``); the calibration from flange and transducer poses, its residual
gate, and the flange pose that puts the focal point on a target (``procedure``); and, beyond the
paper, simulated poses, pose noise and the Monte-Carlo of the calibration error (``sensitivity``);
the calibrated chain run to a target, and the calibration that resolves the transducer's half-turn
symmetry (``targeting``).
"""

from . import axxb as _axxb
from . import dual_quaternion as _dual_quaternion
from . import procedure as _procedure
from . import sensitivity as _sensitivity
from . import targeting as _targeting
from .axxb import AXXBSolution, DegenerateMotionError, daniilidis_matrix, solve_axxb, solve_axxb_dual_quaternions
from .dual_quaternion import dual_quaternion_from_transform, transform_from_dual_quaternion
from .procedure import CalibrationError, HandEyeCalibration, calibrate, flange_pose_for_target, motion_pairs
from .sensitivity import R_BASE_FLANGE_DOWN, calibration_sensitivity, perturb_pose, simulate_poses
from .targeting import DOWN, HALF_TURN, calibrate_half_turns, target_orientation, tcp_for_target

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_axxb.__all__, *_dual_quaternion.__all__, *_procedure.__all__, *_sensitivity.__all__,
                              *_targeting.__all__]))
