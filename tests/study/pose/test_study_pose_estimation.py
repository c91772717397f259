"""Tests of histostudy.study.pose: the one namespace of notebook 04's study keeps every name it
exported before the split (notebook 05 imports from it), each the object of the module that now
holds it, and the old front module's path still gives the package."""

import importlib
import sys

import numpy as np
import pytest

from histostudy.study import pose as study

#: What the module exported before its split by job, and the module of the split that holds each.
HOMES = {
    "DIRECTIONS": "_geometry", "MARGINS": "_geometry", "transducer_axes": "_geometry",
    "margin_positions": "_geometry", "axial_symmetric_rotation_error_deg": "_geometry",
    "rotation_error_modulo_symmetry_deg": "_geometry",
    "random_pose_in_views": "_geometry", "sweep_visible_points": "_geometry",
    "PoseStudyConfig": "_config", "StudyStages": "_config", "study_stages": "_config",
    "PoseExperiment": "_experiments", "experiment_setups": "_experiments", "run_pose_study": "_experiments",
    "REFERENCE_COLUMNS": "_reference", "cbct_reference": "_reference", "phantom_placement": "_reference",
    "experiment_metrics": "_metrics", "table2": "_metrics", "variant_summary": "_metrics",
    "stage_timing": "_metrics", "tracking_summary": "_metrics", "reference_error_summary": "_metrics",
    "robustness_sweep": "_robustness", "robustness_summary": "_robustness",
    "degradation_sweep": "_sweeps", "noise_sweep": "_sweeps",
}


@pytest.mark.parametrize("name, home", sorted(HOMES.items()))
def test_every_name_exported_before_the_split_is_the_object_of_its_new_module(name, home):
    module = importlib.import_module(f"histostudy.study.pose.{home}")
    assert getattr(study, name) is getattr(module, name)


def test_the_old_front_module_path_gives_the_package():
    sys.modules.pop("histostudy.study.pose_estimation", None)
    with pytest.warns(DeprecationWarning, match="histostudy.study.pose_estimation is deprecated"):
        old = importlib.import_module("histostudy.study.pose_estimation")
    assert old is study


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
