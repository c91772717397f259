"""Transducer pose estimation from fluoroscopy (§II-B.3, §II-B.4): per-class distance maps
(``distance_maps``), the eq. 3 cost (``cost``) with its numba kernels (``cost_kernels``) and numpy
reference (``cost_reference``), the left perturbation and normal equations of its Jacobian
(``perturbation``); the initialisation's grid and axial searches (``init``), its silhouette seed
(``silhouette``) and the inner boundary's conic (``conic``, ``conic_orientation``, with the
pipeline's default orientation stage); the refinement (``refine``) and the verdict on a fit
(``verdict``); and :func:`estimate_pose`, which runs them all on a set of frames (``estimate``),
with its options (``options``), its result (``result``) and its default learned stages
(``learned_stages``).
"""

from .conic import (CirclePose, EllipseFit, circle_poses_from_conic, conic_from_ellipse, conic_from_points,
                    fit_ellipse_ransac)
from .conic_orientation import ConicFit, ConicOrientation, default_orientation
from .cost import OUTSIDE_DISTANCE_PX, PARALLEL_MIN_PROJECTIONS, PoseCost
from .distance_maps import DistanceMaps, euclidean_distance_map
from .estimate import estimate_pose
from .init import (COARSE_GRID, FINE_GRID, GridSpec, InitResult, MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG,
                   ROBUST_AXIAL_SEEDS_DEG, axial_minima, axial_search, grid_offsets, grid_search, initialise_pose,
                   rotation_from_direction, translation_costs)
from .learned_stages import LEARNED_STAGE_REQUIREMENTS, default_stages, learned_stage_shortfalls
from .options import INIT_METHODS, MAP_KINDS, MODES, PoseOptions
from .perturbation import NormalEquations, apply_left_perturbation
from .refine import RefineResult, refine_levenberg_marquardt, refine_nelder_mead
from .result import PoseEstimationError, PoseResult
from .silhouette import SILHOUETTE_CELL_PX, segmented_occupancy, silhouette_candidates, silhouette_seed
from .verdict import (PoseVerdict, check_unexplained, check_view_agreement, judge_fit, unexplained_fraction,
                      view_disagreement_mm)

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
    "PoseOptions",
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
