"""Transducer pose estimation from fluoroscopy (§II-B.3, §II-B.4): per-class distance maps
(``distance_maps``), the eq. 3 cost (``cost``) with its numba kernels (``cost_kernels``) and numpy
reference (``cost_reference``), the left perturbation and normal equations of its Jacobian
(``perturbation``); the initialisation's grid and axial searches (``init``), its silhouette seed
(``silhouette``) and the inner boundary's conic (``conic``, ``conic_orientation``, with the
pipeline's default orientation stage); the refinement (``refine``) and the verdict on a fit
(``verdict``); :func:`estimate_pose`, which runs them all on a set of frames (``estimate``), and on
the lab's own frame files (``from_files``), with its options (``options``), its result (``result``)
and its default learned stages (``learned_stages``); :class:`Tracker`, which follows the pose
through a stream of frames, warm-starting each estimate from the last (``tracker``), and its fast
warm path on the region where the last pose projects: the region and its view (``tracking_roi``),
its distance maps in reused buffers (``tracking_maps``), the warm estimate (``tracking_warm``), the
pipeline of :meth:`Tracker.track` (``tracking_pipeline``), the fast from-scratch estimate at the label scale (``tracking_scratch``), its options (``tracking_options``)
and the frame pairs it accepts (``tracking_input``).
"""

from . import (conic as _conic, conic_orientation as _conic_orientation, cost as _cost, distance_maps as _distance_maps,
               estimate as _estimate, from_files as _from_files, init as _init, learned_stages as _learned_stages,
               options as _options, perturbation as _perturbation, refine as _refine, result as _result,
               silhouette as _silhouette, tracker as _tracker, tracking_input as _tracking_input, tracking_maps as _tracking_maps,
               tracking_options as _tracking_options, tracking_roi as _tracking_roi,
               tracking_scratch as _tracking_scratch, tracking_warm as _tracking_warm,
               verdict as _verdict)
from .conic import (CirclePose, EllipseFit, circle_poses_from_conic, conic_from_ellipse, conic_from_points,
                    fit_ellipse_ransac)
from .conic_orientation import ConicFit, ConicOrientation, default_orientation
from .cost import OUTSIDE_DISTANCE_PX, PARALLEL_MIN_PROJECTIONS, PoseCost
from .distance_maps import DistanceMaps, euclidean_distance_map
from .estimate import estimate_pose
from .from_files import frames_from_files, pose_from_files, pose_record
from .init import (COARSE_GRID, FINE_GRID, GridSpec, InitResult, MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG,
                   ROBUST_AXIAL_SEEDS_DEG, axial_minima, axial_search, grid_offsets, grid_search, initialise_pose,
                   rotation_from_direction, translation_costs)
from .learned_stages import LEARNED_STAGE_REQUIREMENTS, default_stages, learned_stage_shortfalls
from .options import INIT_METHODS, MAP_KINDS, MODES, PoseOptions
from .perturbation import NormalEquations, apply_left_perturbation
from .refine import RefineResult, refine_levenberg_marquardt, refine_nelder_mead
from .result import PoseEstimationError, PoseResult, add_timings
from .silhouette import SILHOUETTE_CELL_PX, segmented_occupancy, silhouette_candidates, silhouette_seed
from .tracker import Tracker
from .tracking_input import frames_for_views
from .tracking_maps import RegionMaps
from .tracking_options import TrackingOptions
from .tracking_roi import RegionOfInterest, crop_view, region_of_interest
from .tracking_scratch import ScratchEstimator, scaled_pose_options, scratch_estimator
from .tracking_warm import PreparedRegions, RegionEstimator
from .verdict import (PoseVerdict, check_unexplained, check_view_agreement, judge_fit, unexplained_fraction,
                      view_disagreement_mm)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_conic.__all__, *_conic_orientation.__all__, *_cost.__all__, *_distance_maps.__all__,
                              *_estimate.__all__, *_from_files.__all__, *_init.__all__, *_learned_stages.__all__,
                              *_options.__all__, *_perturbation.__all__, *_refine.__all__, *_result.__all__,
                              *_silhouette.__all__, *_tracker.__all__, *_tracking_input.__all__, *_tracking_maps.__all__,
                              *_tracking_options.__all__, *_tracking_roi.__all__, *_tracking_scratch.__all__,
                              *_tracking_warm.__all__,
                              *_verdict.__all__]))
