"""Notebook 04: the paper's pose-estimation study (§II-D, §II-E.3, §III, Table II).

Its modules, one job each: the study's configuration and the frames of an experiment (``_config``),
the experiments run on them (``_experiments``), pose errors and their frames (``_geometry``), the
per-experiment metrics (``_metrics``), the pipeline on frames of
RTK's projector beside ours (``_projectors``), the CBCT reference of the transducer (``_reference``),
Table II and its companions (``_report_tables``), initialisation over random poses
(``_robustness``), the notebook's section (``_section``), the sweeps (``_sweeps``).
"""

from . import (
               _config,
               _experiments,
               _geometry,
               _metrics,
               _projectors,
               _reference,
               _report_tables,
               _robustness,
               _section,
               _sweeps,
)
from ._config import PoseSectionConfig, PoseStudyConfig, StudyStages, study_stages
from ._experiments import PoseExperiment, draw_experiments, experiment_setups, run_pose_study
from ._geometry import (
               DIRECTIONS,
               MARGINS,
               axial_symmetric_rotation_error_deg,
               bubble_cloud_centre_mm,
               experiment_pose,
               margin_positions,
               random_pose_in_views,
               rotation_error_modulo_symmetry_deg,
               sweep_visible_points,
               transducer_axes,
)
from ._metrics import (
               experiment_metrics,
               mean_sd,
               reference_error_summary,
               stage_timing,
               table2,
               tracking_summary,
               variant_summary,
)
from ._projectors import PROJECTORS, comparison_poses, projector_comparison, projector_summary
from ._reference import REFERENCE_COLUMNS, cbct_reference, phantom_placement, reference_by_experiment
from ._report_tables import (
               failed_estimates,
               focal_error_per_dose,
               focal_error_per_level,
               init_success_comparisons,
               stages_comparison_table,
               table2_beside_paper,
               table2_both_references,
               table2_comparisons,
)
from ._robustness import robustness_summary, robustness_sweep
from ._section import PoseOverlay, PoseSection
from ._sweeps import degradation_sweep, noise_sweep

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_config.__all__, *_experiments.__all__, *_geometry.__all__, *_metrics.__all__,
                              *_projectors.__all__, *_reference.__all__, *_report_tables.__all__, *_robustness.__all__, *_section.__all__,
                              *_sweeps.__all__]))

# the 0.1.0 name, deprecated (CHANGELOG.md)
