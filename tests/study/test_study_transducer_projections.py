"""Notebook 01's measurements: geometry measured on the points, counts, label fractions."""

import numpy as np
import pytest

from histostudy.imaging import Frame, default_biplane, render_labels
from histostudy.study import transducer_projections as study
from histostudy.transducer import TransducerModel, TransducerSpec, pose_facing


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(TransducerSpec(), spacing_mm=0.47)


def test_geometry_is_measured_from_the_points(model):
    geo = study.model_geometry(model)
    assert geo["sphere_radius_mm"] == pytest.approx(138.7, abs=1e-6)
    assert np.allclose(geo["sphere_centre_mm"], 0, atol=1e-6)
    assert geo["aperture_x_mm"] == pytest.approx(240.0, abs=2 * 0.47)
    assert geo["aperture_y_mm"] == pytest.approx(170.0, abs=2 * 0.47)
    assert geo["cutout_diameter_mm"] == pytest.approx(64.0, abs=2 * 0.47)
    # a different spec gives different measurements: nothing is copied from the defaults
    other = study.model_geometry(TransducerModel.build(TransducerSpec(radius_mm=150.0, cutout_diameter_mm=50.0), 0.47))
    assert other["sphere_radius_mm"] == pytest.approx(150.0, abs=1e-6)
    assert other["cutout_diameter_mm"] == pytest.approx(50.0, abs=2 * 0.47)


def test_point_count_table(model):
    table = study.point_count_table({"a": model})
    assert table.iloc[-1]["a"] == sum(len(p) for p in model.points.values())
    assert list(table["feature class"][:5]) == ["transducer", "outer_boundary", "inner_boundary", "gaps", "screws"]


def test_label_fraction_table_sums_to_the_image(model):
    view = default_biplane()[1]
    labels = render_labels(model, pose_facing(), view)
    table = study.label_fraction_table([Frame(np.zeros(view.shape, np.float32), view, labels=labels)])
    assert table["pixels"].sum() == labels.size and table["percent"].sum() == pytest.approx(100.0)


def test_render_timing_reports_every_stage(model):
    view = default_biplane()[0].scaled(0.25)
    table = study.render_timing(model, pose_facing(), view, background=np.zeros(view.shape), repeats=2, n_splats=2)
    assert list(table["stage"]) == ["background projection", "transducer splatting", "frame, background precomputed"]
    assert (table["median_s"] > 0).all() and (table["repeats"] == 2).all()
    with pytest.raises(ValueError, match="repeats"):
        study.render_timing(model, pose_facing(), view, background=None, repeats=0)
