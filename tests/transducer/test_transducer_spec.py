"""Tests of histostudy.transducer.spec: the feature classes, the label priority and the spec's checks
and JSON form."""

import numpy as np
import pytest

from histostudy.transducer import FEATURE_CLASSES, LABEL_PRIORITY, Feature, TransducerSpec


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


@pytest.mark.parametrize("labels, match", [
    (np.array([[0, 300]]), r"\[300\]"), (np.array([[-1, 2]]), r"\[-1\]"), (np.array([[2.7, 1.0]]), r"\[2.7\]"),
    (np.array([[np.nan, 1.0]]), "nan"), (np.array([[6, 1]], np.uint8), r"\[6\]"), (np.array(["a"]), "got dtype <U1"),
])
def test_label_images_outside_the_feature_values_are_refused_not_wrapped(labels, match):
    from histostudy.transducer import check_label_image

    with pytest.raises(ValueError, match=match):
        check_label_image(labels if labels.ndim == 2 else labels[None], name="labels")


def test_label_images_of_whole_numbers_become_uint8_and_the_shape_is_checked():
    from histostudy.transducer import check_label_image

    out = check_label_image(np.array([[0.0, 5.0], [3.0, 1.0]]))
    assert out.dtype == np.uint8 and out.tolist() == [[0, 5], [3, 1]]
    assert check_label_image(np.ones((2, 2), bool)).tolist() == [[1, 1], [1, 1]]
    with pytest.raises(ValueError, match=r"shape \(3, 2\)"):
        check_label_image(np.zeros((2, 2), np.uint8), (3, 2), "labels of view 'A'")
