"""Every source's magnitude has a reference entry (value, range, status), and a swept source can be
built at any magnitude of its range."""

import dataclasses

import numpy as np
import pytest

from histostudy.study.budget._references import (
    SOURCE_REFERENCES,
    STATUSES,
    magnitudes_at,
    model_at,
    references_table,
    sweep_values,
)
from histostudy.study.budget._section import SOURCE_PROVENANCE, sources_table
from histostudy.study.budget._sources import LAB_SOURCES, LabErrorModel


def test_every_source_has_a_reference_whose_value_is_its_default():
    assert list(SOURCE_REFERENCES) == list(LAB_SOURCES)
    default = LabErrorModel()
    for name, ref in SOURCE_REFERENCES.items():
        assert ref.status in STATUSES and ref.low <= ref.value <= ref.high, name
        assert ref.reference and ref.mapping and ref.checked, name
        assert magnitudes_at(name, ref.value) == getattr(default, name), name  # the value is the default's
        if ref.status == "swept":
            assert ref.high > ref.low, name
    assert set(SOURCE_PROVENANCE) == set(LAB_SOURCES)
    assert list(references_table()["source"]) == list(LAB_SOURCES)
    assert sources_table(default)["from"].str.len().min() > 20


def test_a_source_at_another_magnitude_keeps_its_shape_and_the_others():
    values = sweep_values("bubble_offset", 5)
    assert values[0] == SOURCE_REFERENCES["bubble_offset"].low and values[-1] == SOURCE_REFERENCES["bubble_offset"].high
    model = model_at("bubble_offset", 2.0)
    assert model.bubble_offset.sd_mm == (1.0, 1.0, 2.0)
    assert dataclasses.replace(model, bubble_offset=LabErrorModel().bubble_offset) == LabErrorModel()
    assert model_at("registration", 0.15).registration.rotation_deg == pytest.approx(0.05)
    manufacturing = magnitudes_at("manufacturing", 2 * SOURCE_REFERENCES["manufacturing"].value)
    assert manufacturing.quadrant_offset_sd_mm == pytest.approx(2 * LabErrorModel().manufacturing.quadrant_offset_sd_mm)
    assert manufacturing.extra_screw_count == LabErrorModel().manufacturing.extra_screw_count
    off = model_at("phantom_motion", 0.3, base=LabErrorModel().off())
    assert off.enabled == ("phantom_motion",) and off.phantom_motion.sd_mm == pytest.approx(0.3)
    assert np.all(np.diff(sweep_values("robot_accuracy", 3)) > 0)
    with pytest.raises(ValueError, match="source must be one of"):
        sweep_values("sag")
    with pytest.raises(ValueError, match="value must be finite"):
        magnitudes_at("robot", -1.0)
    with pytest.raises(ValueError, match="n must be"):
        sweep_values("robot", 1)
