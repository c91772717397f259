"""The notebooks' section configs (histostudy.study.section): each refuses a bad parameter at the
call, naming it, its value and what it must be, and names a missing one with its notebook."""

import dataclasses

import numpy as np
import pytest

from histostudy.study.budget import BudgetSectionConfig
from histostudy.study.orientation import OrientationConfig
from histostudy.study.pose import PoseSectionConfig
from histostudy.study.projections import TransducerProjectionsConfig
from histostudy.study.segmentation import SegmentationConfig
from histostudy.study.targeting import TargetingSectionConfig
from histostudy.study.your_data import YourDataConfig

#: Each notebook's section config and the notebook whose parameters cell makes it.
NB01 = (TransducerProjectionsConfig, "01_transducer_and_projections")
NB02 = (SegmentationConfig, "02_segmentation")
NB03 = (OrientationConfig, "03_orientation")
NB04 = (PoseSectionConfig, "04_pose_estimation")
NB05 = (TargetingSectionConfig, "05_targeting")
NB06 = (YourDataConfig, "06_your_data")
NB07 = (BudgetSectionConfig, "07_error_budget")

#: (config class, notebook, parameter, bad value, what the message says it must be)
CASES = [
    (*NB01, "photons_per_pixel", 0.0, "a finite number > 0"),
    (*NB01, "n_splats", 2.5, "an integer >= 1"),
    (*NB01, "splat_sigma_mm", "0.5", "a finite number > 0 mm"),
    (*NB01, "pose_spacing_mm", -0.47, "a finite number > 0 mm"),
    (*NB01, "render_spacing_mm", float("nan"), "a finite number > 0 mm"),
    (*NB01, "background", "liver", "one of 'phantom', 'abdomen', 'mixed', 'none'"),
    (*NB01, "timing_repeats", 0, "an integer >= 1"),
    (*NB01, "render_3d", "yes", "True or False"),
    (*NB01, "splat_device", None, "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB02, "splat_device", "gpu", "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB05, "splat_device", "CPU", "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB04, "splat_device", "gpu", "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB06, "splat_device", 0, "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB07, "splat_device", "compiled", "one of 'numpy', 'cpu', 'cuda', 'auto'"),
    (*NB02, "photons_per_pixel", -1.0, "a finite number > 0"),
    (*NB02, "n_splats", 0, "an integer >= 1"),
    (*NB02, "splat_sigma_mm", None, "a finite number > 0 mm"),
    (*NB02, "render_spacing_mm", float("inf"), "a finite number > 0 mm"),
    (*NB02, "background", "Mixed", "one of 'phantom', 'abdomen', 'mixed', 'none'"),
    (*NB02, "n_eval_images", 4.0, "an integer >= 1"),
    (*NB02, "weights", None, 'a checkpoint path or ""'),
    (*NB02, "cache_frames", 1, "True or False"),
    (*NB02, "render_workers", 0, "an integer >= 1"),
    (*NB03, "geometric_initialiser", "no", "True or False"),
    (*NB03, "n_eval_images", -4, "an integer >= 1"),
    (*NB03, "background", 3, "one of 'phantom', 'abdomen', 'mixed', 'none'"),
    (*NB03, "splat_sigma_mm", 0.0, "a finite number > 0 mm"),
    (*NB05, "pose_spacing_mm", 0.0, "a finite number > 0 mm"),
    (*NB05, "n_experiments", 0, "an integer >= 1"),
    (*NB05, "n_calibration_poses", 2, "an integer >= 3"),
    (*NB05, "zone_diameters_mm", "20", "finite diameters in mm"),
    (*NB05, "treatment_spacing_mm", [2.0, 2.0], "3 finite numbers (mm)"),
    (*NB05, "bubble_offset_mm", [0.0, np.nan, 0.0], "3 finite numbers (mm)"),
    (*NB05, "learned_stages", "yes", "True or False"),
    (*NB05, "robot", "ur5e", "one of 'sim', 'rtde', 'both'"),
    (*NB05, "n_figure_experiments", -1, "an integer >= 0"),
    (*NB05, "sensitivity_poses", [2, 4], "integers >= 3"),
    (*NB05, "sensitivity_noise", [0.25, 0.1], "(translation SD mm, rotation SD deg) pairs"),
    (*NB05, "sensitivity_trials", 2.5, "an integer >= 1"),
    (*NB05, "render_3d", None, "True or False"),
    (*NB05, "zone_diameters_mm", (40.0,), "diameters in (0, 30] mm"),  # TargetingStudyConfig's check
    (*NB05, "pose_mode", "slow", "'paper' or 'fast'"),
    (*NB06, "target_mm", [1.0, 2.0], "3 finite numbers"),
    (*NB06, "target_mm", [1.0, np.nan, 2.0], "3 finite numbers"),
    (*NB06, "target_mm", "1, 2, 3", "3 finite numbers"),
    (*NB06, "n_cine_frames", 0, "an integer >= 1"),
    (*NB06, "n_cine_frames", 2.5, "an integer >= 1"),
    (*NB06, "max_tracked_frames", -1, "None or an integer >= 1"),
    (*NB06, "max_queued_pairs", True, "None or an integer >= 1"),
    (*NB06, "stream_cine", "yes", "True or False"),
    (*NB06, "dry_run", 0, "True or False"),
    (*NB06, "moving_cine_s", -2.0, "a finite number >= 0 s"),
    (*NB06, "moving_cine_fps", 0.0, "a finite number > 0 frames/s"),
    (*NB06, "moving_cine_speed_mm_s", float("inf"), "a finite number > 0 mm/s"),
    (*NB06, "photons_per_pixel", -5.0, "a finite number > 0"),
    (*NB06, "n_splats", 0, "an integer >= 1"),
    (*NB06, "splat_sigma_mm", "0.5", "a finite number > 0 mm"),
    (*NB06, "pose_spacing_mm", 0, "a finite number > 0 mm"),
    (*NB06, "speed_mm_s", -50.0, "a finite number > 0 mm/s"),
    (*NB06, "robot_host", "", "None or the UR controller's host"),
    (*NB06, "robot_host", 5, "None or the UR controller's host"),
    (*NB06, "data_dir", 3, "None or a folder path"),
    (*NB07, "photons_per_pixel", 0, "a finite number > 0"),
    (*NB07, "n_splats", -1, "an integer >= 1"),
    (*NB07, "render_spacing_mm", "0.25", "a finite number > 0 mm"),
    (*NB07, "background", "water", "one of 'phantom', 'abdomen', 'mixed', 'none'"),
    (*NB07, "pose_experiments", 1.5, "an integer >= 1"),
    (*NB07, "targeting_experiments", 0, "an integer >= 1"),
    (*NB07, "learned_stages", 1, "True or False"),
    (*NB07, "sources", "robot", "a list of the names"),
    (*NB07, "sources", ["robot", "robot"], "name each of"),
    (*NB07, "sources", ["gravity"], "name each of"),
    (*NB07, "scheduler", None, '"" (HISTOSTUDY_SCHEDULER, else here)'),
]


@pytest.mark.parametrize("config, notebook, name, value, expected", CASES)
def test_a_bad_parameter_is_refused_naming_it_its_value_and_what_it_must_be(config, notebook, name, value, expected,
                                                                          notebook_parameters,
                                                                          assert_parameter_refused):
    stored = notebook_parameters(notebook)
    defaults = {field.name: stored[field.name] for field in dataclasses.fields(config)}
    assert_parameter_refused(config, defaults, name, value, expected)


@pytest.mark.parametrize("config, notebook", [NB01, NB02, NB03, NB05, NB06, NB07])
def test_the_stored_parameters_cell_makes_the_config_and_the_report_records_its_fields(config, notebook,
                                                                                     notebook_parameters):
    cell = notebook_parameters(notebook)
    params = config.from_parameters(cell)
    fields = [field.name for field in dataclasses.fields(config)]
    assert set(cell) - set(fields) == {"profile", "seed", "output_dir"}
    recorded = params.recorded()
    assert recorded and set(recorded) <= set(fields) and all(recorded[k] == getattr(params, k) for k in recorded)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(params, fields[0], None)
