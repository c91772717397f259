"""Tests of histostudy.transducer.digital: the digital model's geometry against the paper's numbers."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, TransducerSpec

SPEC = TransducerSpec()
R, A_HALF, B_HALF, RC = 138.7, 120.0, 85.0, 32.0


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


def on_cap(points):
    """Points on the spherical surface (cap classes), not on walls or in screws."""
    return np.abs(np.linalg.norm(points, axis=1) - R) < 1e-9


def test_every_class_is_present_and_weights_are_physical(model):
    for f in FEATURE_CLASSES:
        assert model.points[f].shape[1] == 3 and len(model.points[f]) > 0, f
        assert model.weights[f].shape == (len(model.points[f]),)
    assert np.all(model.weights[Feature.GAPS] == 0.0)
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.SCREWS):
        assert np.all(model.weights[f] > 0), f
    # Element weight = mu * thickness * surface element spacing² R / z.
    p = model.points[Feature.TRANSDUCER]
    expected = SPEC.element_mu_per_mm * SPEC.element_thickness_mm * 0.47 ** 2 * R / p[:, 2]
    np.testing.assert_allclose(model.weights[Feature.TRANSDUCER], expected, rtol=1e-12)
    # Screws keep their total attenuation mu * volume whatever the grid.
    volume = SPEC.screw_count * np.pi * 1.5 ** 2 * 8.0
    assert model.weights[Feature.SCREWS].sum() == pytest.approx(SPEC.screw_mu_per_mm * volume, rel=1e-9)
    pts, classes = model.all_points()
    assert pts.shape == (sum(model.n_points.values()), 3) and classes.dtype == np.uint8
    assert np.all(np.diff(classes.astype(int)) >= 0)
    assert model.all_weights().shape == (len(pts),)


def test_point_counts_scale_with_inverse_spacing_squared(model):
    fine = TransducerModel.build(spacing_mm=0.25)
    ratio = (0.47 / 0.25) ** 2
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY):
        assert fine.n_points[f] / model.n_points[f] == pytest.approx(ratio, rel=0.05), f
    assert 150_000 <= sum(model.n_points.values()) <= 250_000


def test_sphere_fit_of_elements_gives_radius_and_focal_point(model):
    p = model.points[Feature.TRANSDUCER][::7]
    fit = least_squares(lambda q: np.linalg.norm(p - q[:3], axis=1) - q[3], x0=[5.0, -5.0, 10.0, 120.0])
    np.testing.assert_allclose(fit.x[:3], 0.0, atol=1e-6)
    assert fit.x[3] == pytest.approx(R, abs=1e-6)
    assert np.all(p[:, 2] > 0)  # +z from the focal point towards the transducer


def test_aperture_cutout_and_bands(model):
    cap = np.vstack([model.points[f][on_cap(model.points[f])] for f in FEATURE_CLASSES[:4]])
    x, y = cap[:, 0], cap[:, 1]
    r = np.hypot(x, y)
    assert np.all((x / A_HALF) ** 2 + (y / B_HALF) ** 2 <= 1 + 1e-12)
    assert np.abs(x).max() == pytest.approx(A_HALF, abs=0.47) and np.abs(y).max() == pytest.approx(B_HALF, abs=0.47)
    assert r.min() >= RC and r.min() == pytest.approx(RC, abs=0.47)
    # Full aperture widths and cutout diameter as specified.
    assert np.ptp(x) == pytest.approx(240.0, abs=0.94) and np.ptp(y) == pytest.approx(170.0, abs=0.94)
    inner = model.points[Feature.INNER_BOUNDARY]
    assert np.hypot(inner[:, 0], inner[:, 1]).max() < RC + 3.0 + 1e-9
    outer = model.points[Feature.OUTER_BOUNDARY]
    oc = outer[on_cap(outer)]
    assert np.all((oc[:, 0] / (A_HALF - 3)) ** 2 + (oc[:, 1] / (B_HALF - 3)) ** 2 > 1)
    el = model.points[Feature.TRANSDUCER]
    assert np.all((el[:, 0] / (A_HALF - 3)) ** 2 + (el[:, 1] / (B_HALF - 3)) ** 2 <= 1)
    assert np.hypot(el[:, 0], el[:, 1]).min() >= RC + 3.0
    gaps = model.points[Feature.GAPS]
    assert np.all(np.minimum(np.abs(gaps[:, 0]), np.abs(gaps[:, 1])) < 0.75)
    assert np.all(np.minimum(np.abs(el[:, 0]), np.abs(el[:, 1])) >= 0.75)


def test_walls_rise_in_plus_z_at_the_edges(model):
    outer = model.points[Feature.OUTER_BOUNDARY]
    wall = outer[~on_cap(outer)]
    ellipse = (wall[:, 0] / A_HALF) ** 2 + (wall[:, 1] / B_HALF) ** 2
    np.testing.assert_allclose(ellipse, 1.0, atol=1e-6)
    z_edge = np.sqrt(R ** 2 - wall[:, 0] ** 2 - wall[:, 1] ** 2)
    assert np.all(wall[:, 2] > z_edge) and np.all(wall[:, 2] < z_edge + SPEC.outer_wall_height_mm)


def test_cap_area_matches_the_analytic_spherical_area(model):
    """Sum of the cap's surface elements against the integral of R r / sqrt(R² - r²) over the aperture."""
    s = model.spacing_mm
    area = 0.0
    for f in FEATURE_CLASSES[:4]:
        p = model.points[f][on_cap(model.points[f])]
        area += np.sum(s * s * R / p[:, 2])
    phi = np.linspace(0, 2 * np.pi, 200_001)[:-1]
    r_edge = 1 / np.sqrt((np.cos(phi) / A_HALF) ** 2 + (np.sin(phi) / B_HALF) ** 2)
    analytic = np.mean(R * (np.sqrt(R ** 2 - RC ** 2) - np.sqrt(R ** 2 - r_edge ** 2))) * 2 * np.pi
    assert area == pytest.approx(analytic, rel=5e-3)


@pytest.mark.parametrize("spacing", [0.0, -0.47, float("nan"), float("inf")])
def test_bad_spacing_raises(spacing):
    with pytest.raises(ValueError, match="spacing_mm"):
        TransducerModel.build(spacing_mm=spacing)


def test_only_keeps_the_chosen_classes_and_everything_else():
    model = TransducerModel.build(spacing_mm=2.0)
    gaps = model.only(Feature.GAPS)
    for f in FEATURE_CLASSES:
        expected = model.points[f] if f == Feature.GAPS else np.zeros((0, 3))
        np.testing.assert_array_equal(gaps.points[f], expected)
        assert len(gaps.weights[f]) == len(gaps.points[f])
    assert gaps.spacing_mm == model.spacing_mm and gaps.grid_step_mm == model.grid_step_mm
    np.testing.assert_array_equal(gaps.focal_point_mm, model.focal_point_mm)
    with pytest.raises(ValueError, match="point classes"):
        model.only(Feature.BACKGROUND)
