"""Notebook 05: the paper's automated targeting study (§II-C, §II-D, §II-E.4, §III, Fig. 7).

Its modules, one job each: the configuration and the ground truth an experiment draws (``_setup``),
the simulated robots (``_robots``), hand-eye calibration (``_calibration``, §II-C), positioning the
TCP on a CBCT target (``_positioning``, §II-D), treating a zone (``_treatment``), one experiment and
the study of several (``_experiment``), §III's figures, tables and comparisons (``_summary``), Fig.
7's cuts and scene (``_figures``), the notebook's parameters, set-up and text (``_notebook``), and the
notebook's namespace (``_study``).
"""

from . import _calibration, _experiment, _figures, _notebook, _positioning, _robots, _setup, _summary, _treatment, _study
from ._calibration import (HALF_TURN, calibrate_robot, calibration_poses, config_focal_flange)
from ._experiment import (calibration_errors, run_targeting_experiment, run_targeting_study, zone_errors)
from ._figures import (SceneFigure, fig7_figures, plot_target_slices, scene_figure)
from ._notebook import (RECORDED_PARAMETERS, SECTION_TITLE, NotebookSeeds, TargetingSetup, closing_text, config_from_parameters, notebook_seeds, prepare_study, run_prepared_study, stand_ins)
from ._positioning import (DOWN, position_for_target, scene_at_target, target_orientation, tcp_for_target)
from ._robots import (robot_seed, rtde_robot, sim_robot)
from ._setup import (GroundTruth, TargetingError, TargetingStudyConfig, draw_ground_truth, start_joints)
from ._summary import (CALIBRATION_TABLE_CAPTION, ERROR_TABLE_CAPTION, SUMMARY_TABLE_CAPTION, calibration_table, error_table, first_robot_rows, robot_max_difference, sensitivity_caption, sensitivity_medians, calibration_sensitivity_table, summary, targeting_comparisons, targeting_values)
from ._treatment import (learn_bubble_bias, phantom_for, treat_zone)
from ._study import (CALIBRATION_TABLE_CAPTION, DOWN, ERROR_TABLE_CAPTION, HALF_TURN, R_BASE_FLANGE_DOWN, RECORDED_PARAMETERS, SECTION_TITLE, SUMMARY_TABLE_CAPTION, GroundTruth, NotebookSeeds, SceneFigure, TargetingError, TargetingSetup, TargetingStudyConfig, calibrate_robot, calibration_errors, calibration_poses, calibration_sensitivity_table, calibration_table, closing_text, config_focal_flange, config_from_parameters, draw_ground_truth, error_table, fig7_figures, first_robot_rows, learn_bubble_bias, notebook_seeds, phantom_for, plot_target_slices, position_for_target, prepare_study, robot_max_difference, robot_seed, rtde_robot, run_prepared_study, run_targeting_experiment, run_targeting_study, scene_at_target, scene_figure, sensitivity_caption, sensitivity_medians, sim_robot, stand_ins, start_joints, summary, target_orientation, targeting_comparisons, targeting_values, tcp_for_target, treat_zone, zone_errors)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_calibration.__all__, *_experiment.__all__, *_figures.__all__, *_notebook.__all__, *_positioning.__all__, *_robots.__all__, *_setup.__all__, *_summary.__all__, *_treatment.__all__, *_study.__all__]))
