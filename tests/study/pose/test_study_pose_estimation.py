"""Tests of histostudy.study.pose._study: the one namespace of notebook 04's study keeps every name
it exported before the split (notebook 05 and histostudy.study.targeting._study import from it), each the
object of the module that now holds it, and the old private names alias the public ones."""

import importlib

import numpy as np
import pytest

from histostudy.study import pose as study

#: What the module exported before its split by job, and the module of the split that holds each.
HOMES = {
    "DIRECTIONS": "pose_geometry", "MARGINS": "pose_geometry", "transducer_axes": "pose_geometry",
    "margin_positions": "pose_geometry", "axial_symmetric_rotation_error_deg": "pose_geometry",
    "rotation_error_modulo_symmetry_deg": "pose_geometry",
    "random_pose_in_views": "pose_geometry", "sweep_visible_points": "pose_geometry",
    "PoseStudyConfig": "pose_config", "StudyStages": "pose_config", "study_stages": "pose_config",
    "PoseExperiment": "pose_experiments", "experiment_setups": "pose_experiments", "run_pose_study": "pose_experiments",
    "REFERENCE_COLUMNS": "pose_reference", "cbct_reference": "pose_reference", "phantom_placement": "pose_reference",
    "experiment_metrics": "pose_metrics", "table2": "pose_metrics", "variant_summary": "pose_metrics",
    "stage_timing": "pose_metrics", "tracking_summary": "pose_metrics", "reference_error_summary": "pose_metrics",
    "robustness_sweep": "pose_robustness", "robustness_summary": "pose_robustness",
    "degradation_sweep": "pose_sweeps", "noise_sweep": "pose_sweeps",
}


@pytest.mark.parametrize("name, home", sorted(HOMES.items()))
def test_every_name_exported_before_the_split_is_the_object_of_its_new_module(name, home):
    module = importlib.import_module(f"histostudy.study.{home}")
    assert getattr(study, name) is getattr(module, name)


def test_the_old_private_names_alias_the_public_ones():
    assert study._mean_sd is study.mean_sd
    assert study._experiment_pose is study.experiment_pose
    assert study._bubble_centre is study.bubble_cloud_centre_mm


def test_all_names_every_public_name_once_and_each_resolves():
    assert len(study.__all__) == len(set(study.__all__))
    assert set(HOMES) <= set(study.__all__)
    for name in study.__all__:
        assert getattr(study, name) is not None, name


def test_mean_sd_is_the_sample_sd_of_the_finite_values():
    mean, sd = study.mean_sd([1.0, 2.0, np.nan, 6.0, np.inf])
    assert mean == pytest.approx(3.0) and sd == pytest.approx(np.std([1.0, 2.0, 6.0], ddof=1))
    assert study.mean_sd([4.0]) == (4.0, 0.0)
    assert all(np.isnan(v) for v in study.mean_sd([np.nan]))
