"""Transducer pose estimation from fluoroscopy (§II-B.3, §II-B.4).

:func:`estimate_pose` (``estimate``) runs its stages, each its own function, on a set of frames:
the labels and their distance maps (``labels``, ``distance_maps``), the eq. 3 costs at their
truncations (``truncations``; the cost itself, its numba kernels and numpy reference in the
sub-package ``cost``, the left perturbation and normal equations of its Jacobian in
``perturbation``), each view's direction candidates (``directions``; the inner boundary's conic in
``conic`` and ``conic_orientation``, with the pipeline's default orientation stage), the
initialisation (``start``, over the grid and axial searches of ``init`` and the silhouette seed of
``silhouette``), the refinement (``refine``), the verdict on a fit (``verdict``) and the retries
after a refused one (``retries``). :func:`estimate_pose_from_labels` (``from_labels``) runs them
from labels; ``from_files`` runs :func:`estimate_pose` on the lab's own frame files. Its options
and seeding rule (``options``), its result (``result``) and its default learned stages
(``learned_stages``). The sub-package ``tracking`` follows the pose through a stream of frames
(:class:`Tracker`), with its fast warm path on the region where the last pose projects.

Poses are 4x4 ``T_carm_transducer`` (mm, C-arm/CBCT frame; docs/architecture.md).
"""

from . import conic as _conic
from . import conic_orientation as _conic_orientation
from . import cost as _cost
from . import directions as _directions
from . import distance_maps as _distance_maps
from . import estimate as _estimate
from . import from_files as _from_files
from . import from_labels as _from_labels
from . import init as _init
from . import labels as _labels
from . import learned_stages as _learned_stages
from . import options as _options
from . import perturbation as _perturbation
from . import refine as _refine
from . import result as _result
from . import retries as _retries
from . import silhouette as _silhouette
from . import start as _start
from . import tracking as _tracking
from . import truncations as _truncations
from . import verdict as _verdict
from .conic import (
               CirclePose,
               EllipseFit,
               circle_poses_from_conic,
               conic_from_ellipse,
               conic_from_points,
               fit_ellipse_ransac,
)
from .conic_orientation import ConicFit, ConicOrientation, default_orientation
from .cost import OUTSIDE_DISTANCE_PX, PARALLEL_MIN_PROJECTIONS, PoseCost
from .directions import DirectionStage, SourceDirections, check_direction_pair, unit_direction_pair
from .distance_maps import DistanceMaps, euclidean_distance_map
from .estimate import estimate_pose
from .from_files import frames_from_files, half_turn_reading, match_views, pose_from_files, pose_record
from .from_labels import estimate_pose_from_labels
from .init import (
               COARSE_GRID,
               FINE_GRID,
               MEDIUM_GRID,
               PAPER_AXIAL_SEEDS_DEG,
               ROBUST_AXIAL_SEEDS_DEG,
               GridSpec,
               InitResult,
               axial_minima,
               axial_search,
               grid_offsets,
               grid_search,
               initialise_pose,
               rotation_from_direction,
               translation_costs,
)
from .labels import clean_labels, segment_frames, view_distance_maps
from .learned_stages import LEARNED_STAGE_REQUIREMENTS, default_stages, learned_stage_shortfalls
from .options import DEFAULT_SEED, INIT_METHODS, MAP_KINDS, MODES, PoseConfig, pose_generator
from .perturbation import NormalEquations, apply_left_perturbation
from .refine import RefineResult, refine_levenberg_marquardt, refine_nelder_mead, refine_pose
from .result import PoseEstimationError, PoseResult, add_timings, refused, result_of_refinement
from .retries import Refined, refine_with_retries
from .silhouette import SILHOUETTE_CELL_PX, segmented_occupancy, silhouette_candidates, silhouette_seed
from .start import SILHOUETTE_POINTS, Initialisation, coarse_scorings, directions_to_try, initialise
from .tracking import (
               PreparedRegions,
               RegionEstimator,
               RegionMaps,
               RegionOfInterest,
               RegionPlan,
               ScratchEstimator,
               Tracker,
               TrackingConfig,
               crop_view,
               frames_for_views,
               region_of_interest,
               scaled_pose_options,
               scratch_estimator,
               views_isocentre_mm,
               warm_up_pair,
)
from .truncations import PoseCosts, pose_costs
from .verdict import (
               PoseJudge,
               PoseVerdict,
               check_unexplained,
               check_view_agreement,
               judge_fit,
               unexplained_fraction,
               view_disagreement_mm,
)

# every public name of the modules and sub-packages above, as each declares it in __all__
__all__ = list(dict.fromkeys([*_conic.__all__, *_conic_orientation.__all__, *_cost.__all__, *_directions.__all__,
                              *_distance_maps.__all__, *_estimate.__all__, *_from_files.__all__, *_from_labels.__all__,
                              *_init.__all__, *_labels.__all__, *_learned_stages.__all__, *_options.__all__,
                              *_perturbation.__all__, *_refine.__all__, *_result.__all__, *_retries.__all__,
                              *_silhouette.__all__, *_start.__all__, *_tracking.__all__, *_truncations.__all__,
                              *_verdict.__all__]))

# the 0.1.0 names, deprecated (CHANGELOG.md)
