"""Transducer pose estimation from fluoroscopy (§II-B.3, §II-B.4): distance maps and the eq. 3 cost
(``cost``), the initialisation (``init``; the inner boundary's conic, ``conic`` and
``conic_orientation``), the refinement (``refine``), the verdict on a fit (``verdict``) and
:func:`estimate_pose`, which runs them all on a set of frames (``estimate``).
"""

from .conic import (CirclePose, EllipseFit, circle_poses_from_conic, conic_from_ellipse, conic_from_points,
                    fit_ellipse_ransac)
from .conic_orientation import ConicFit, ConicOrientation, default_orientation
from .cost import (DistanceMaps, NormalEquations, OUTSIDE_DISTANCE_PX, PARALLEL_MIN_PROJECTIONS, PoseCost,
                   apply_left_perturbation, euclidean_distance_map)
from .estimate import (INIT_METHODS, LEARNED_STAGE_REQUIREMENTS, MAP_KINDS, MODES, PoseEstimationError, PoseResult,
                       PoseVerdict, default_stages, estimate_pose, learned_stage_shortfalls, unexplained_fraction,
                       view_disagreement_mm)
from .init import (COARSE_GRID, FINE_GRID, GridSpec, InitResult, MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG,
                   ROBUST_AXIAL_SEEDS_DEG, SILHOUETTE_CELL_PX, axial_minima, axial_search, grid_offsets, grid_search,
                   initialise_pose, rotation_from_direction, segmented_occupancy, silhouette_candidates,
                   silhouette_seed, translation_costs)
from .refine import RefineResult, refine_levenberg_marquardt, refine_nelder_mead
from .verdict import check_unexplained, check_view_agreement, judge_fit

__all__ = [
    "COARSE_GRID",
    "CirclePose",
    "ConicFit",
    "ConicOrientation",
    "DistanceMaps",
    "EllipseFit",
    "FINE_GRID",
    "GridSpec",
    "INIT_METHODS",
    "InitResult",
    "LEARNED_STAGE_REQUIREMENTS",
    "MAP_KINDS",
    "MEDIUM_GRID",
    "MODES",
    "NormalEquations",
    "OUTSIDE_DISTANCE_PX",
    "PAPER_AXIAL_SEEDS_DEG",
    "PARALLEL_MIN_PROJECTIONS",
    "PoseCost",
    "PoseEstimationError",
    "PoseResult",
    "PoseVerdict",
    "ROBUST_AXIAL_SEEDS_DEG",
    "RefineResult",
    "SILHOUETTE_CELL_PX",
    "apply_left_perturbation",
    "axial_minima",
    "axial_search",
    "check_unexplained",
    "check_view_agreement",
    "circle_poses_from_conic",
    "conic_from_ellipse",
    "conic_from_points",
    "default_orientation",
    "default_stages",
    "estimate_pose",
    "euclidean_distance_map",
    "fit_ellipse_ransac",
    "grid_offsets",
    "grid_search",
    "initialise_pose",
    "judge_fit",
    "learned_stage_shortfalls",
    "refine_levenberg_marquardt",
    "refine_nelder_mead",
    "rotation_from_direction",
    "segmented_occupancy",
    "silhouette_candidates",
    "silhouette_seed",
    "translation_costs",
    "unexplained_fraction",
    "view_disagreement_mm",
]
