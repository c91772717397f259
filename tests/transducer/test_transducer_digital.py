"""Tests of histostudy.transducer: model geometry against the paper's numbers, the physical model."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from histostudy.geometry import check_rigid, rotvec_from_matrix
from histostudy.imaging import default_biplane
from histostudy.transducer import (FEATURE_CLASSES, Feature, LABEL_PRIORITY, ManufacturingDeviation, TransducerModel,
                                   TransducerSpec, pose_facing, quadrant_index)

SPEC = TransducerSpec()
R, A_HALF, B_HALF, RC = 138.7, 120.0, 85.0, 32.0


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


def on_cap(points):
    """Points on the spherical surface (cap classes), not on walls or in screws."""
    return np.abs(np.linalg.norm(points, axis=1) - R) < 1e-9


def test_enum_and_priority_match_the_paper():
    assert [int(f) for f in Feature] == [0, 1, 2, 3, 4, 5]
    assert FEATURE_CLASSES == (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY,
                               Feature.GAPS, Feature.SCREWS)
    assert LABEL_PRIORITY[0] is Feature.SCREWS and LABEL_PRIORITY[-1] is Feature.TRANSDUCER
    assert set(LABEL_PRIORITY) == set(FEATURE_CLASSES)


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


@pytest.mark.parametrize("spacing", [0.0, -0.47, float("nan"), float("inf")])
def test_bad_spacing_raises(spacing):
    with pytest.raises(ValueError, match="spacing_mm"):
        TransducerModel.build(spacing_mm=spacing)


def test_spec_round_trips_through_json(tmp_path):
    spec = TransducerSpec(gap_width_mm=2.0, screw_count=6)
    assert TransducerSpec.from_dict(spec.to_dict()) == spec
    path = spec.save(tmp_path / "spec.json")
    assert TransducerSpec.load(path) == spec
    (tmp_path / "bare.json").write_text('{"radius_mm": 150.0}')
    assert TransducerSpec.load(tmp_path / "bare.json").radius_mm == 150.0
    with pytest.raises(ValueError, match="unknown"):
        TransducerSpec.from_dict({"radius": 1.0})


def test_physical_model_is_seed_deterministic():
    a = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))
    b = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))
    c = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(4))
    for f in FEATURE_CLASSES:
        assert np.array_equal(a.points[f], b.points[f]) and np.array_equal(a.weights[f], b.weights[f])
    assert not np.array_equal(a.points[Feature.TRANSDUCER], c.points[Feature.TRANSDUCER])
    np.testing.assert_array_equal(a.focal_point_mm, b.focal_point_mm)


def test_physical_quadrants_move_rigidly_and_focal_point_follows():
    digital = TransducerModel.build(spacing_mm=1.0)
    phys = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0))
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.GAPS):
        d, p = digital.points[f], phys.points[f]
        q = quadrant_index(d)
        for k in range(4):
            T = check_rigid(phys.quadrant_transforms[k])
            np.testing.assert_allclose(p[q == k], d[q == k] @ T[:3, :3].T + T[:3, 3], atol=1e-9)
    np.testing.assert_allclose(phys.focal_point_mm, phys.quadrant_transforms[:, :3, 3].mean(axis=0))
    assert 0 < np.linalg.norm(phys.focal_point_mm) < 2.0


def test_physical_deviation_has_the_requested_size():
    """Pooled over seeds, recovered quadrant offsets and tilts have the requested SDs."""
    offsets, tilts = [], []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        shift = TransducerModel.build_physical(spacing_mm=4.0, rng=rng, deviation=ManufacturingDeviation(
            quadrant_offset_sd_mm=0.2, quadrant_tilt_sd_deg=0.0, extra_screw_count=0))
        digital = TransducerModel.build(spacing_mm=4.0)
        d, p = digital.points[Feature.TRANSDUCER], shift.points[Feature.TRANSDUCER]
        q = quadrant_index(d)
        offsets += [(p[q == k] - d[q == k]).mean(axis=0) for k in range(4)]
        tilt = TransducerModel.build_physical(spacing_mm=4.0, rng=rng, deviation=ManufacturingDeviation(
            quadrant_offset_sd_mm=0.0, quadrant_tilt_sd_deg=0.15, extra_screw_count=0))
        tilts += [rotvec_from_matrix(_kabsch(d[q == k], tilt.points[Feature.TRANSDUCER][q == k])) for k in range(4)]
    assert np.std(offsets) == pytest.approx(0.2, rel=0.2)
    assert np.rad2deg(np.std(tilts)) == pytest.approx(0.15, rel=0.2)


def _kabsch(src, dst):
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1, 1, d]) @ u.T


def test_zero_deviation_equals_digital_and_extra_screws_sit_beyond_the_apex():
    digital = TransducerModel.build(spacing_mm=1.0)
    none = ManufacturingDeviation(quadrant_offset_sd_mm=0, quadrant_tilt_sd_deg=0, extra_screw_count=0)
    same = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0), deviation=none)
    for f in FEATURE_CLASSES:
        np.testing.assert_allclose(same.points[f], digital.points[f], atol=1e-12)
    three = ManufacturingDeviation(quadrant_offset_sd_mm=0, quadrant_tilt_sd_deg=0, extra_screw_count=3)
    extra = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0), deviation=three)
    n_dig = digital.n_points[Feature.SCREWS]
    new = extra.points[Feature.SCREWS][n_dig:]
    assert len(new) == 3 * n_dig // SPEC.screw_count
    assert np.all(new[:, 2] > R)


def test_pose_facing_puts_the_transducer_above_the_patient():
    T = check_rigid(pose_facing())
    centre = T[:3, :3] @ [0, 0, R] + T[:3, 3]
    np.testing.assert_allclose(centre, [0, -R, 0], atol=1e-9)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)  # LR along patient left
    T2 = pose_facing((0, 1, 0), focal_point_mm=(5, 6, 7), axial_rotation_rad=np.pi / 2)
    np.testing.assert_allclose(T2[:3, 3], [5, 6, 7])
    np.testing.assert_allclose(T2[:3, 2], [0, -1, 0], atol=1e-12)
    view_a, _ = default_biplane()
    Tv = pose_facing(view_a)
    np.testing.assert_allclose(Tv[:3, 2], -view_a.principal_direction, atol=1e-12)
    with pytest.raises(ValueError, match="direction"):
        pose_facing((0, 0, 0))


def test_only_keeps_the_chosen_classes_and_everything_else():
    from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel

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
