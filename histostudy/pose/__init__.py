"""Transducer pose estimation from a biplane pair of fluoroscopy frames (§II-B.3, §II-B.4):
:func:`estimate_pose` and its stages from labels (:func:`estimate_pose_from_labels`), their options
(:class:`PoseConfig`) and result (:class:`PoseResult`), the pose from a lab's frame files
(``from_files``) and the :class:`Tracker` that follows the pose through a stream of frames.
Poses are 4x4 T_carm_transducer in mm; the stages are described in docs/pose-estimation.md.
"""

from .conic_orientation import ConicOrientation, default_orientation
from .cost import PoseCost
from .directions import SourceDirections
from .distance_maps import DistanceMaps
from .estimate import estimate_pose
from .estimate_memo import shared_estimates
from .from_files import frames_from_files, half_turn_reading, match_views, pose_from_files, pose_record
from .from_labels import estimate_pose_from_labels
from .learned_stages import LEARNED_STAGE_REQUIREMENTS, default_stages, learned_stage_shortfalls
from .options import MAP_KINDS, PoseConfig
from .perturbation import apply_left_perturbation
from .refine import refine_levenberg_marquardt, refine_nelder_mead
from .result import PoseEstimationError, PoseResult
from .tracking import RegionEstimator, Tracker, TrackingConfig

__all__ = [
    # the estimate, its options and its result
    "estimate_pose",
    "estimate_pose_from_labels",
    "PoseConfig",
    "MAP_KINDS",
    "PoseResult",
    "PoseEstimationError",
    # estimates made once within a scope (a study's runs that repeat one)
    "shared_estimates",
    # its learned stages and the orientation stage
    "default_stages",
    "learned_stage_shortfalls",
    "LEARNED_STAGE_REQUIREMENTS",
    "default_orientation",
    "ConicOrientation",
    "SourceDirections",
    # eq. 3's cost and its refinements
    "DistanceMaps",
    "PoseCost",
    "apply_left_perturbation",
    "refine_nelder_mead",
    "refine_levenberg_marquardt",
    # the pose from a lab's frame files
    "frames_from_files",
    "match_views",
    "pose_from_files",
    "pose_record",
    "half_turn_reading",
    # tracking through a stream of frames
    "Tracker",
    "TrackingConfig",
    "RegionEstimator",
]
