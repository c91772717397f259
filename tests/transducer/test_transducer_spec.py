"""Tests of histostudy.transducer.spec: the feature classes, the label priority and the spec's checks
and JSON form."""

import pytest

from histostudy.transducer import FEATURE_CLASSES, Feature, LABEL_PRIORITY, TransducerSpec


def test_enum_and_priority_match_the_paper():
    assert [int(f) for f in Feature] == [0, 1, 2, 3, 4, 5]
    assert FEATURE_CLASSES == (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY,
                               Feature.GAPS, Feature.SCREWS)
    assert LABEL_PRIORITY[0] is Feature.SCREWS and LABEL_PRIORITY[-1] is Feature.TRANSDUCER
    assert set(LABEL_PRIORITY) == set(FEATURE_CLASSES)


@pytest.mark.parametrize("kwargs, name", [
    ({"cutout_diameter_mm": 200.0}, "cutout_diameter_mm"),
    ({"cutout_diameter_mm": 170.0}, "cutout_diameter_mm"),
    ({"gap_width_mm": -1.0}, "gap_width_mm"),
    ({"aperture_x_mm": -240.0}, "aperture_x_mm"),
    ({"outer_band_mm": float("nan")}, "outer_band_mm"),
    ({"aperture_x_mm": 300.0}, "radius_mm"),
    ({"screw_count": -1}, "screw_count"),
])
def test_bad_spec_raises_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        TransducerSpec(**kwargs)


def test_spec_round_trips_through_json(tmp_path):
    spec = TransducerSpec(gap_width_mm=2.0, screw_count=6)
    assert TransducerSpec.from_dict(spec.to_dict()) == spec
    path = spec.save(tmp_path / "spec.json")
    assert TransducerSpec.load(path) == spec
    (tmp_path / "bare.json").write_text('{"radius_mm": 150.0}')
    assert TransducerSpec.load(tmp_path / "bare.json").radius_mm == 150.0
    with pytest.raises(ValueError, match="unknown"):
        TransducerSpec.from_dict({"radius": 1.0})
