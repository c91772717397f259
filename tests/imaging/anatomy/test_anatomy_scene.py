"""Tests of histostudy.imaging.anatomy._scene: projections of a scene into a C-arm view against exact
values and brute-force line integrals, the renderer's culling, threads and oversampling, and a
user's static background."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import Anatomy, View, default_biplane
from histostudy.imaging.anatomy._random import random_abdomen, random_phantom_setup
from histostudy.imaging.anatomy._scene import StaticBackground
from histostudy.imaging.anatomy._shapes import Ellipsoid

SMALL = dict(shape=(96, 124), pixel_mm=3.08)     # a 1240x960 detector binned 10x


def numeric_line_integral(anatomy, origin, direction, t_range=(100.0, 1500.0), dt=0.02):
    # The scenes reach at most ~600 mm from the isocentre; the source is 785 mm from it.
    t = np.arange(t_range[0] + dt / 2.0, t_range[1], dt)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return float(anatomy.attenuation(np.asarray(origin, float) + t[:, None] * d).sum() * dt)


# --- projections ---------------------------------------------------------------------------------


@pytest.mark.parametrize("view", default_biplane(), ids=lambda v: v.name)
def test_centred_sphere_gives_two_r_mu_at_the_principal_point(view):
    r, mu = 40.0, 0.021
    sphere = Ellipsoid([0.0, 0.0, 0.0], [r, r, r], mu_per_mm=mu)
    rows, cols = view.shape
    d = view.ray_directions([[(cols - 1) / 2.0, (rows - 1) / 2.0]])
    assert sphere.line_integrals_of_rays(view.source_mm, d)[0] == pytest.approx(2 * r * mu, rel=1e-12)
    # Through the renderer: an odd detector puts the principal point on a pixel centre.
    odd = View.from_gantry(view.gantry["primary_deg"], shape=(97, 125), pixel_mm=3.08)
    img = Anatomy((sphere,)).line_integrals(odd)
    assert img.dtype == np.float32 and img.shape == (97, 125)
    assert img[48, 62] == pytest.approx(2 * r * mu, rel=1e-6)
    assert img.max() == img[48, 62]


@pytest.mark.parametrize("view", default_biplane(), ids=lambda v: v.name)
def test_off_centre_sphere_peaks_where_its_centre_projects(view):
    center = np.array([35.0, -20.0, 25.0])
    img = Anatomy((Ellipsoid(center, [12.0, 12.0, 12.0], mu_per_mm=0.05),)).line_integrals(view)
    u, v = view.project(center)[0]
    row, col = np.unravel_index(np.argmax(img), img.shape)
    assert abs(col - u) <= 1.0 and abs(row - v) <= 1.0
    assert img.max() == pytest.approx(2 * 12.0 * 0.05, rel=1e-3)


def test_renderer_matches_brute_force_line_integrals_of_a_scene():
    anatomy = random_abdomen(np.random.default_rng(11))
    view = View.from_gantry(-45.0, **SMALL)
    img = anatomy.line_integrals(view)
    pixels = [(10, 20), (48, 62), (60, 100), (90, 5)]
    d = view.ray_directions([[c, r] for r, c in pixels])
    for (r, c), direction in zip(pixels, d):
        want = numeric_line_integral(anatomy, view.source_mm, direction)
        assert img[r, c] == pytest.approx(want, abs=2e-3)


def test_culling_and_threads_do_not_change_the_image():
    view = View.from_gantry(0.0, **SMALL)
    for anatomy in (random_abdomen(np.random.default_rng(1)), random_phantom_setup(np.random.default_rng(1))):
        ref = anatomy.line_integrals(view, cull=False, workers=1)
        assert np.array_equal(anatomy.line_integrals(view, cull=True, workers=1), ref)
        assert np.array_equal(anatomy.line_integrals(view, cull=True, workers=2), ref)


def test_oversampling_averages_sub_pixel_rays():
    anatomy = random_abdomen(np.random.default_rng(2))
    view = View.from_gantry(30.0, **SMALL)
    img = anatomy.line_integrals(view, oversample=2)
    shifted = []
    for du in (-0.25, 0.25):
        for dv in (-0.25, 0.25):
            # Pixel (c, r) of the shifted view is pixel (c + du, r + dv) of the original one.
            S = np.array([[1.0, 0.0, -du], [0.0, 1.0, -dv], [0.0, 0.0, 1.0]])
            shifted.append(anatomy.line_integrals(View(P=S @ view.P, shape=view.shape, pixel_mm=view.pixel_mm)))
    assert np.allclose(img, np.mean(shifted, axis=0), atol=1e-5)


def test_moving_the_scene_equals_moving_the_view():
    anatomy = random_phantom_setup(np.random.default_rng(7))
    T = make_transform(rotation_about_axis([0.2, 1.0, 0.1], 0.3), [10.0, -5.0, 20.0])
    view = View.from_gantry(-45.0, **SMALL)
    moved = anatomy.transformed(T).line_integrals(view)
    view_in_old_frame = View(P=view.P @ T, shape=view.shape, pixel_mm=view.pixel_mm)
    assert np.allclose(moved, anatomy.line_integrals(view_in_old_frame), atol=1e-4)


def test_static_background_wraps_a_users_projection():
    view_a, view_b = default_biplane(shape=(96, 124), pixel_mm=3.08)
    image = np.random.default_rng(0).uniform(0.0, 6.0, size=(96, 124))
    bg = StaticBackground(image, view=view_a, name="pig03_A")
    out = bg.line_integrals(view_a)
    assert out.dtype == np.float32 and np.allclose(out, image, atol=1e-6)
    out[0, 0] = -1.0
    assert bg.line_integrals(view_a)[0, 0] != -1.0           # a copy each time
    with pytest.raises(ValueError, match="view 'B'"):
        bg.line_integrals(view_b)
    with pytest.raises(ValueError, match="shape"):
        StaticBackground(image).line_integrals(View.from_gantry(0.0, shape=(48, 62), pixel_mm=6.16))


# --- errors --------------------------------------------------------------------------------------


def test_bad_input_errors_name_the_argument():
    with pytest.raises(ValueError, match="oversample"):
        Anatomy(()).line_integrals(View.from_gantry(0.0, **SMALL), oversample=0)
    with pytest.raises(ValueError, match="primitives\\[0\\]"):
        Anatomy(("sphere",))
