"""Tests of histostudy.study.pose: the package gives notebook 04's section (its config, prepare, the
parts and record) and the sweeps its callers use, each the object of the module that holds it."""

import importlib

import numpy as np
import pytest

from histostudy.study import pose as study
from histostudy.study import section
from histostudy.study.pose.metrics import mean_sd

#: Names of the package and the module that defines each.
HOMES = {
    "PoseSectionConfig": "_section", "prepare": "_section", "experiments_part": "_section",
    "cbct_reference_part": "_section", "table2_part": "_section", "variants_part": "_section",
    "pose_overlay": "_section", "robustness_part": "_section", "degradation_part": "_section",
    "learned_stages_part": "_section", "projector_part": "_section", "closing_part": "_section",
    "robustness_sweep": "_robustness", "robustness_summary": "_robustness",
}


@pytest.mark.parametrize("name, home", sorted(HOMES.items()))
def test_each_name_is_the_object_of_its_module(name, home):
    module = importlib.import_module(f"histostudy.study.pose.{home}")
    assert getattr(study, name) is getattr(module, name)


def test_the_package_exports_the_section_s_shape():
    assert len(study.__all__) == len(set(study.__all__)) and set(HOMES) <= set(study.__all__)
    assert study.record is section.record
    assert issubclass(study.PoseSectionConfig, section.SectionConfig)
    assert [n for n in study.__all__ if n.endswith("Config")] == ["PoseSectionConfig"]


def test_mean_sd_is_the_sample_sd_of_the_finite_values():
    mean, sd = mean_sd([1.0, 2.0, np.nan, 6.0, np.inf])
    assert mean == pytest.approx(3.0) and sd == pytest.approx(np.std([1.0, 2.0, 6.0], ddof=1))
    assert mean_sd([4.0]) == (4.0, 0.0)
    assert all(np.isnan(v) for v in mean_sd([np.nan]))
