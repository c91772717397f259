"""Tests of histostudy.imaging.render._reference: splatting against ray integrals, labels, noise statistics, frames."""

import numpy as np
import pytest

from histostudy.imaging import (
    Frame,
    View,
    add_poisson_noise,
    default_biplane,
    render_frame,
    render_labels,
    render_line_integrals,
)
from histostudy.imaging.render._reference import ZERO_COUNT_CLAMP
from histostudy.transducer import FEATURE_CLASSES, LABEL_PRIORITY, Feature, TransducerModel, TransducerSpec, pose_facing

R = 138.7
MU_T = 1.4 * 2.0  # element mu * thickness of the default spec


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


@pytest.fixture(scope="module")
def views():
    return default_biplane()


def test_public_call_returns_a_complete_frame(model, views):
    view_a, _ = views
    T = pose_facing()
    frame = render_frame(model, T, view_a, rng=np.random.default_rng(0))
    assert isinstance(frame, Frame) and frame.view is view_a
    assert frame.image.shape == view_a.shape and frame.image.dtype == np.float32
    assert frame.labels.shape == view_a.shape and frame.labels.dtype == np.uint8
    np.testing.assert_array_equal(frame.T_carm_transducer, T)
    assert frame.meta["n_splats"] == 16 and frame.meta["photons_per_pixel"] == 5e4
    assert np.all(np.isfinite(frame.image))


def test_rendering_is_seed_deterministic(model, views):
    view_a, _ = views
    T = pose_facing()
    a = render_frame(model, T, view_a, rng=np.random.default_rng(7))
    b = render_frame(model, T, view_a, rng=np.random.default_rng(7))
    c = render_frame(model, T, view_a, rng=np.random.default_rng(8))
    assert np.array_equal(a.image, b.image) and np.array_equal(a.labels, b.labels)
    assert not np.array_equal(a.image, c.image)


@pytest.mark.parametrize("plane", [0, 1])
def test_every_class_appears_in_the_standard_pose(model, views, plane):
    labels = render_labels(model, pose_facing(), views[plane])
    present = set(np.unique(labels).tolist())
    assert present == {int(f) for f in Feature}, present


def test_splatting_conserves_attenuation(model):
    """With every copy on the detector, the image sums to sum(weight / footprint) over the points."""
    big = View.from_gantry(-45.0, 0.0, shape=(1400, 1600), pixel_mm=0.5)
    T = pose_facing()
    image = render_line_integrals(model, T, big, rng=np.random.default_rng(0))
    pts, _ = model.all_points()
    world = pts @ T[:3, :3].T + T[:3, 3]
    assert np.all(big.in_image(big.project(world)))
    assert np.count_nonzero(image[[0, -1], :]) == 0 and np.count_nonzero(image[:, [0, -1]]) == 0
    expected = np.sum(model.all_weights() / big.pixel_footprint_mm2(world))
    assert image.sum(dtype=np.float64) == pytest.approx(expected, rel=1e-5)


def test_line_integral_through_the_cap_is_mu_t_over_cos_incidence(model, views):
    """Independent check: rendered value where a ray crosses one element = mu t / |cos(incidence)|."""
    view_a, _ = views
    rows, cols = view_a.shape
    checked = 0
    for T in (pose_facing(view_a), pose_facing()):
        image = render_line_integrals(model, T, view_a, rng=np.random.default_rng(2), n_splats=64)
        for x, y in [(50.0, 40.0), (-60.0, -30.0), (20.0, -60.0), (80.0, 10.0)]:
            p = T[:3, :3] @ [x, y, np.sqrt(R ** 2 - x * x - y * y)] + T[:3, 3]
            col, row = np.floor(view_a.project(p)[0] + 0.5).astype(int)
            if not (10 <= col < cols - 10 and 10 <= row < rows - 10):
                continue
            checked += 1
            ray = (p - view_a.source_mm) / np.linalg.norm(p - view_a.source_mm)
            normal = (p - T[:3, 3]) / R
            expected = MU_T / abs(ray @ normal)
            window = image[row - 10:row + 11, col - 10:col + 11]
            assert window.mean() == pytest.approx(expected, rel=0.04), (x, y)
    assert checked >= 6


def test_points_behind_the_source_or_off_detector_add_nothing(model, views):
    view_a, _ = views
    behind = pose_facing(view_a, focal_point_mm=view_a.source_mm - 400 * view_a.principal_direction)
    assert not render_line_integrals(model, behind, view_a, rng=np.random.default_rng(0)).any()
    aside = pose_facing(focal_point_mm=(2000.0, 0.0, 0.0))
    assert not render_line_integrals(model, aside, view_a, rng=np.random.default_rng(0)).any()
    assert not render_labels(model, aside, view_a).any()


@pytest.mark.parametrize("order", [1.0, -1.0])
def test_label_priority_wins_overlaps(order):
    """All classes at one place: the label is the highest-priority class present, whatever the depth."""
    x, z = np.meshgrid(np.linspace(-3, 3, 25), np.linspace(-3, 3, 25))
    patch = np.column_stack([x.ravel(), np.zeros(x.size), z.ravel()])
    view = View.from_gantry(0.0, 0.0, shape=(64, 64), pixel_mm=0.5)  # beam along -y
    depth = {f: order * 5.0 * i for i, f in enumerate(FEATURE_CLASSES)}  # order 1: screws nearest the source
    for k in range(len(LABEL_PRIORITY)):
        present = LABEL_PRIORITY[k:]
        points = {f: (patch + [0, depth[f], 0]) if f in present else np.zeros((0, 3)) for f in FEATURE_CLASSES}
        weights = {f: np.ones(len(points[f])) for f in FEATURE_CLASSES}
        toy = TransducerModel(spec=TransducerSpec(), spacing_mm=0.25, points=points, weights=weights)
        labels = render_labels(toy, np.eye(4), view)
        assert labels[32, 32] == int(LABEL_PRIORITY[k])
        assert labels[0, 0] == 0


def test_screw_in_front_of_an_element_is_labelled_screw(model, views):
    view_a, _ = views
    T = pose_facing()
    labels = render_labels(model, T, view_a)
    screws = model.points[Feature.SCREWS]
    px = np.floor(view_a.project(screws @ T[:3, :3].T + T[:3, 3]) + 0.5).astype(int)
    on = view_a.in_image(px)
    assert on.any()
    assert np.all(labels[px[on, 1], px[on, 0]] == Feature.SCREWS)


@pytest.mark.parametrize("spacing", [0.125, 0.47])
def test_labels_have_no_pinholes(views, spacing):
    model = TransducerModel.build(spacing_mm=spacing)
    view_a, _ = views
    for T in (pose_facing(), pose_facing(view_a)):
        labels = render_labels(model, T, view_a)
        fg = np.pad(labels > 0, 1)
        background = ~fg[1:-1, 1:-1]
        neighbours = sum(np.roll(np.roll(fg, dr, 0), dc, 1)[1:-1, 1:-1]
                         for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0))
        assert np.count_nonzero(background & (neighbours >= 7)) == 0
        element = labels == Feature.TRANSDUCER
        assert element.sum() > 10_000


def test_poisson_noise_statistics():
    rng = np.random.default_rng(0)
    p, n0 = 1.5, 1e4
    noisy = add_poisson_noise(np.full((200, 200), p), n0, rng)
    assert noisy.dtype == np.float32
    var = np.exp(p) / n0
    assert noisy.mean() == pytest.approx(p, abs=4 * np.sqrt(var / noisy.size) + 1 / (2 * n0 * np.exp(-p)))
    assert noisy.var() == pytest.approx(var, rel=0.05)
    dark = add_poisson_noise(np.full((4, 4), 40.0), 5e4, rng)
    np.testing.assert_allclose(dark, -np.log(ZERO_COUNT_CLAMP / 5e4), rtol=1e-6)
    for bad in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError, match="photons_per_pixel"):
            add_poisson_noise(np.zeros((2, 2)), bad, rng)


def test_bad_pose_and_arguments_raise(model, views):
    view_a, _ = views
    shear = np.eye(4)
    shear[0, 1] = 0.3
    for fn in (lambda T: render_line_integrals(model, T, view_a, rng=np.random.default_rng(0)),
               lambda T: render_labels(model, T, view_a),
               lambda T: render_frame(model, T, view_a, rng=np.random.default_rng(0))):
        with pytest.raises(ValueError, match="T_carm_transducer"):
            fn(shear)
    T = pose_facing()
    with pytest.raises(ValueError, match="n_splats"):
        render_line_integrals(model, T, view_a, rng=np.random.default_rng(0), n_splats=0)
    with pytest.raises(ValueError, match="splat_sigma_mm"):
        render_line_integrals(model, T, view_a, rng=np.random.default_rng(0), splat_sigma_mm=-1.0)
    with pytest.raises(TypeError, match="rng"):
        render_line_integrals(model, T, view_a, rng=0)
    with pytest.raises(ValueError, match="labels_from"):
        render_frame(model, T, view_a, rng=np.random.default_rng(0), labels_from="cad")
    with pytest.raises(ValueError, match="background"):
        render_frame(model, T, view_a, rng=np.random.default_rng(0), background=np.zeros((3, 3)))


class FlatAnatomy:
    """Duck-typed stand-in for histostudy.imaging.anatomy._random: anything with line_integrals(view)."""

    def line_integrals(self, view):
        return np.full(view.shape, 0.7)


def test_hybrid_image_is_background_plus_transducer(model, views):
    view_a, _ = views
    T = pose_facing()
    transducer = render_line_integrals(model, T, view_a, rng=np.random.default_rng(5))
    back = np.linspace(0, 2, view_a.shape[0] * view_a.shape[1]).reshape(view_a.shape)
    frame = render_frame(model, T, view_a, rng=np.random.default_rng(5), background=back, photons_per_pixel=None)
    np.testing.assert_allclose(frame.image, back + transducer, atol=1e-5)
    duck = render_frame(model, T, view_a, rng=np.random.default_rng(5), background=FlatAnatomy(),
                        photons_per_pixel=None)
    np.testing.assert_allclose(duck.image, 0.7 + transducer, atol=1e-5)
    assert duck.meta["background"] == "FlatAnatomy"


def test_physical_transducer_makes_the_image_digital_model_the_labels(model, views):
    view_a, _ = views
    T = pose_facing()
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(1))
    frame = render_frame(model, T, view_a, rng=np.random.default_rng(3), physical=physical, photons_per_pixel=None)
    expected = render_line_integrals(physical, T, view_a, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(frame.image, expected)
    np.testing.assert_array_equal(frame.labels, render_labels(model, T, view_a))
    own = render_frame(model, T, view_a, rng=np.random.default_rng(3), physical=physical,
                       photons_per_pixel=None, labels_from="physical")
    np.testing.assert_array_equal(own.labels, render_labels(physical, T, view_a))
    assert not np.array_equal(own.labels, frame.labels)
