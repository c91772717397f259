"""Notebook 04: the paper's pose-estimation experiment (§II-D, §II-E.3, §III, Table II), in one namespace.

The study is split by job; this module gathers their public names, as the notebook and notebook
05 import them (``from histostudy.study import pose as study``):

- :mod:`.pose_config` — :class:`PoseStudyConfig` and the stages the estimates run on;
- :mod:`.pose_geometry` — the error directions of §II-E (depth, TB, LR), the margin poses,
  the random poses of the sweeps (C-arm frame, mm);
- :mod:`.pose_experiments` — the experiments of Table II: drawn, rendered, estimated;
- :mod:`.pose_reference` — the post-treatment CBCT reference (§II-D, §II-E.3);
- :mod:`.pose_metrics` — Table II and the other summaries (mm, mean ± SD);
- :mod:`.pose_robustness`, :mod:`.pose_sweeps` — beyond the paper: initialisation success over
  random poses, error vs segmentation quality and vs dose;
- :mod:`.pose_section`, :mod:`.pose_report_tables` — the notebook's report section, part by part,
  and its tables.

``_mean_sd``, ``_experiment_pose`` and ``_bubble_centre`` are the old private names of
:func:`mean_sd`, :func:`experiment_pose` and :func:`bubble_cloud_centre_mm`, kept for the code
that still imports them from here.
"""

from __future__ import annotations

from ._config import PoseSectionParameters, PoseStudyConfig, StudyStages, study_stages
from ._experiments import PoseExperiment, draw_experiments, experiment_setups, run_pose_study
from ._geometry import (DIRECTIONS, MARGINS, axial_symmetric_rotation_error_deg, rotation_error_modulo_symmetry_deg, bubble_cloud_centre_mm,
                            experiment_pose, margin_positions, random_pose_in_views, sweep_visible_points,
                            transducer_axes)
from ._metrics import (experiment_metrics, mean_sd, reference_error_summary, stage_timing, table2,
                           tracking_summary, variant_summary)
from ._reference import REFERENCE_COLUMNS, cbct_reference, phantom_placement, reference_by_experiment
from ._robustness import robustness_summary, robustness_sweep
from ._report_tables import (failed_estimates, focal_error_per_dose, focal_error_per_level,
                                 init_success_comparisons, stages_comparison_table, table2_beside_paper,
                                 table2_both_references, table2_comparisons)
from ._section import PoseOverlay, PoseSection
from ._sweeps import degradation_sweep, noise_sweep

_mean_sd = mean_sd
_experiment_pose = experiment_pose
_bubble_centre = bubble_cloud_centre_mm

__all__ = [
    "DIRECTIONS",
    "MARGINS",
    "REFERENCE_COLUMNS",
    "PoseExperiment",
    "PoseOverlay",
    "PoseSection",
    "PoseSectionParameters",
    "PoseStudyConfig",
    "StudyStages",
    "axial_symmetric_rotation_error_deg",
    "rotation_error_modulo_symmetry_deg",
    "bubble_cloud_centre_mm",
    "cbct_reference",
    "degradation_sweep",
    "draw_experiments",
    "experiment_metrics",
    "experiment_pose",
    "experiment_setups",
    "failed_estimates",
    "focal_error_per_dose",
    "focal_error_per_level",
    "init_success_comparisons",
    "margin_positions",
    "mean_sd",
    "noise_sweep",
    "phantom_placement",
    "random_pose_in_views",
    "reference_by_experiment",
    "reference_error_summary",
    "robustness_summary",
    "robustness_sweep",
    "run_pose_study",
    "stage_timing",
    "stages_comparison_table",
    "study_stages",
    "sweep_visible_points",
    "table2",
    "table2_beside_paper",
    "table2_both_references",
    "table2_comparisons",
    "tracking_summary",
    "transducer_axes",
    "variant_summary",
]
