"""Tests of histostudy.imaging.anatomy: analytic chords against brute-force sampling, projections, scenes."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, random_rotation, rotation_about_axis
from histostudy.imaging import (AbdomenParams, Anatomy, Box, Difference, Ellipsoid, EllipticCylinder, Intersection,
                                MIXED_ABDOMEN_PROBABILITY, StaticBackground, View, default_biplane, random_abdomen,
                                random_background, random_phantom_setup)

SMALL = dict(shape=(96, 124), pixel_mm=3.08)     # a 1240x960 detector binned 10x


def numeric_chord(contains, origin, direction, t_range=(0.0, 1200.0), dt=0.01):
    """Independent reference: midpoint-rule length of the ray inside a solid, by point tests.

    ``t_range`` (mm along the ray) must cover the solid; the tests' solids lie 500-1000 mm away.
    """
    t = np.arange(t_range[0] + dt / 2.0, t_range[1], dt)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    pts = np.asarray(origin, float) + t[:, None] * d
    return float(contains(pts).sum() * dt)


def numeric_line_integral(anatomy, origin, direction, t_range=(100.0, 1500.0), dt=0.02):
    # The scenes reach at most ~600 mm from the isocentre; the source is 785 mm from it.
    t = np.arange(t_range[0] + dt / 2.0, t_range[1], dt)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return float(anatomy.attenuation(np.asarray(origin, float) + t[:, None] * d).sum() * dt)


def rays_towards(rng, origin, target, spread, n):
    """n unit directions from origin towards points scattered around target."""
    pts = np.asarray(target) + rng.uniform(-spread, spread, size=(n, 3))
    d = pts - origin
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# --- primitives against brute force --------------------------------------------------------------


def test_ellipsoid_chord_matches_point_sampling():
    rng = np.random.default_rng(3)
    ell = Ellipsoid([20.0, -15.0, 30.0], [60.0, 25.0, 40.0], random_rotation(rng), mu_per_mm=0.02)
    origin = np.array([400.0, 500.0, -200.0])
    dirs = rays_towards(rng, origin, ell.center_mm, 35.0, 12)
    got = ell.chord_lengths(origin, dirs)
    want = [numeric_chord(ell.contains, origin, d) for d in dirs]
    assert np.count_nonzero(want) >= 6                      # most rays hit, some may miss
    assert np.allclose(got, want, atol=0.03)


def test_chord_from_an_origin_inside_counts_only_the_part_ahead():
    ell = Ellipsoid([0.0, 0.0, 0.0], [30.0, 20.0, 10.0])
    dirs = np.eye(3)
    assert np.allclose(ell.chord_lengths([0.0, 0.0, 0.0], dirs), [30.0, 20.0, 10.0])
    box = Box([0.0, 0.0, 0.0], [30.0, 20.0, 10.0])
    assert np.allclose(box.chord_lengths([5.0, 0.0, 0.0], dirs), [25.0, 20.0, 10.0])
    # A solid entirely behind the origin is not seen.
    assert np.allclose(ell.chord_lengths([100.0, 0.0, 0.0], [[1.0, 0.0, 0.0]]), 0.0)


def test_box_chord_matches_point_sampling():
    rng = np.random.default_rng(4)
    box = Box([-10.0, 25.0, 5.0], [50.0, 12.0, 30.0], random_rotation(rng), mu_per_mm=0.03)
    origin = np.array([-300.0, 600.0, 150.0])
    dirs = rays_towards(rng, origin, box.center_mm, 50.0, 12)
    got = box.chord_lengths(origin, dirs)
    want = [numeric_chord(box.contains, origin, d) for d in dirs]
    assert np.count_nonzero(want) >= 6
    assert np.allclose(got, want, atol=0.03)


def test_box_ray_along_a_face_plane_and_axis_parallel_rays():
    box = Box([0.0, 0.0, 0.0], [10.0, 10.0, 10.0])
    # Rays parallel to two slabs (direction components exactly 0), inside and outside them.
    got = box.chord_lengths([0.0, 0.0, -100.0], [[0.0, 0.0, 1.0]])
    assert np.allclose(got, 20.0)
    assert np.allclose(box.chord_lengths([15.0, 0.0, -100.0], [[0.0, 0.0, 1.0]]), 0.0)


def test_elliptic_cylinder_chord_matches_point_sampling_and_axis_rays():
    rng = np.random.default_rng(5)
    cyl = EllipticCylinder([5.0, -20.0, 10.0], [45.0, 25.0], 35.0, random_rotation(rng), mu_per_mm=0.02)
    origin = np.array([350.0, 450.0, 300.0])
    dirs = rays_towards(rng, origin, cyl.center_mm, 45.0, 12)
    want = [numeric_chord(cyl.contains, origin, d) for d in dirs]
    assert np.count_nonzero(want) >= 6
    assert np.allclose(cyl.chord_lengths(origin, dirs), want, atol=0.03)
    # Along the axis: inside the cross-section the chord is the full length, outside it misses.
    axis = cyl.R[:, 2]
    inside = cyl.center_mm + cyl.R[:, 0] * 40.0 - 200.0 * axis
    outside = cyl.center_mm + cyl.R[:, 0] * 46.0 - 200.0 * axis
    assert np.allclose(cyl.chord_lengths(inside, axis[None]), 70.0)
    assert np.allclose(cyl.chord_lengths(outside, axis[None]), 0.0)


def test_intersection_and_difference_match_point_sampling():
    rng = np.random.default_rng(6)
    cyl = EllipticCylinder([0.0, 0.0, 0.0], [80.0, 50.0], 100.0, rotation_about_axis([0, 1, 0], 0.2))
    cut = Box([0.0, -20.0, 0.0], [100.0, 50.0, 120.0])
    flattened = Intersection((cyl, cut), mu_per_mm=0.02)
    bath = Difference(Box([0.0, -70.0, 0.0], [60.0, 40.0, 60.0]), flattened, mu_per_mm=0.019)
    origin = np.array([500.0, 550.0, 40.0])
    dirs = rays_towards(rng, origin, [0.0, -40.0, 0.0], 60.0, 12)
    for solid in (flattened, bath):
        want = [numeric_chord(solid.contains, origin, d) for d in dirs]
        assert np.count_nonzero(want) >= 6
        assert np.allclose(solid.chord_lengths(origin, dirs), want, atol=0.04)


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


# --- random scenes -------------------------------------------------------------------------------


def test_same_seed_same_image_other_seed_other_image():
    view = View.from_gantry(-45.0, **SMALL)
    for kind in ("abdomen", "phantom"):
        a = random_background(np.random.default_rng(5), kind).line_integrals(view)
        b = random_background(np.random.default_rng(5), kind).line_integrals(view)
        c = random_background(np.random.default_rng(6), kind).line_integrals(view)
        assert np.array_equal(a, b)
        assert np.abs(a - c).max() > 0.05


def test_abdomen_line_integrals_are_plausible_and_non_negative():
    views = default_biplane(shape=(96, 124), pixel_mm=3.08)
    medians = []
    for seed in range(4):
        anatomy = random_abdomen(np.random.default_rng(seed))
        body_only = Anatomy(tuple(p for p in anatomy.primitives if p.name == "body (fat)"))
        no_bath = Anatomy(tuple(p for p in anatomy.primitives if "bath" not in p.name and p.name != "table"))
        for view in views:
            img = anatomy.line_integrals(view)
            assert np.all(np.isfinite(img)) and img.min() >= 0.0
            in_body = body_only.line_integrals(view) > 0.5
            assert in_body.mean() > 0.5
            body = no_bath.line_integrals(view)[in_body]
            assert 2.0 < np.median(body) < 8.0 and body.max() < 12.0
            medians.append(np.median(img[in_body]))
    assert 3.0 < np.median(medians) < 10.0          # body plus water bath and table


def test_abdomen_attenuation_is_never_negative():
    # Gas pockets only replace tissue that is there: no point has a negative attenuation.
    rng = np.random.default_rng(0)
    for seed in range(3):
        anatomy = random_abdomen(np.random.default_rng(seed), gas_pockets=9)
        pts = rng.uniform([-200.0, -250.0, -200.0], [200.0, 200.0, 200.0], size=(20_000, 3))
        gas = [p for p in anatomy.primitives if "gas" in p.name]
        assert gas
        # Points in and around each gas pocket, out to its edges.
        near_gas = np.concatenate([p.center_mm + rng.normal(0, p.semi_axes_mm.max(), size=(1500, 3)) for p in gas])
        mu = anatomy.attenuation(np.vstack([pts, near_gas]))
        assert mu.min() >= -1e-12
        assert mu.max() < 0.1                       # overlapping bones stay bone-like


def test_abdomen_landmarks_and_overrides():
    anatomy = random_abdomen(np.random.default_rng(8), target_depth_mm=80.0, body_shift_x_mm=0.0,
                             body_yaw_deg=0.0, bath_probability=0.0)
    assert anatomy.kind == "abdomen"
    assert anatomy.meta["target_depth_mm"] == 80.0
    assert not any("bath" in p.name for p in anatomy.primitives)
    # The skin is 80 mm anterior of the isocentre, the table under the back.
    assert anatomy.attenuation([[0.0, -79.0, 0.0]])[0] > 0.015
    assert anatomy.attenuation([[0.0, -81.0, 0.0]])[0] == 0.0
    top = anatomy.meta["table_top_y_mm"]
    assert anatomy.attenuation([[0.0, top + 5.0, 0.0]])[0] > 0.0
    with_bath = random_abdomen(np.random.default_rng(8))
    y_top = with_bath.meta["bath_top_y_mm"]
    c = with_bath.meta["bath_center_mm"]
    assert with_bath.attenuation([[c[0], y_top + 5.0, c[2]]])[0] == pytest.approx(with_bath.meta["mu_water_per_mm"])


def test_params_are_named_ranges_that_overrides_replace():
    params = AbdomenParams(fat_mm=12.0, liver_semi_axes_mm=(40.0, (30.0, 35.0), 60.0))
    assert params.fat_mm == (12.0, 12.0)
    assert params.liver_semi_axes_mm == ((40.0, 40.0), (30.0, 35.0), (60.0, 60.0))
    anatomy = random_abdomen(np.random.default_rng(3), params, rib_pairs=0, gas_pockets=0,
                             stomach_gas_probability=0.0)
    liver = [p for p in anatomy.primitives if p.name == "liver"][0]
    assert liver.semi_axes_mm[0] == pytest.approx(40.0) and 30.0 <= liver.semi_axes_mm[1] <= 35.0
    assert not any(p.name in ("rib", "bowel gas", "stomach gas") for p in anatomy.primitives)
    assert anatomy.meta["fat_mm"] == 12.0
    with pytest.raises(ValueError, match="liver_semi_axes_mm must be 3 ranges"):
        AbdomenParams(liver_semi_axes_mm=(40.0, 50.0))
    with pytest.raises(ValueError, match="rib_pairs must be a range of non-negative integers"):
        AbdomenParams(rib_pairs=(2.5, 4))
    with pytest.raises(ValueError, match="bath_probability must be a probability"):
        AbdomenParams(bath_probability=1.5)


def test_phantom_setup_has_a_layered_cube_near_the_isocentre():
    anatomy = random_phantom_setup(np.random.default_rng(9))
    assert anatomy.kind == "phantom" and anatomy.meta["layered"]
    pc = np.array(anatomy.meta["phantom_center_mm"])
    assert np.all(np.abs(pc) <= 10.0)
    # Along the vertical through the phantom: layers of two attenuations alternate inside it.
    y = np.linspace(-24.0, 24.0, 400)
    mu = anatomy.attenuation(np.column_stack([np.full_like(y, pc[0]), pc[1] + y, np.full_like(y, pc[2])]))
    levels = np.unique(np.round(mu, 6))
    assert len(levels) == 2 and levels[1] - levels[0] > 0.003
    assert np.count_nonzero(np.diff(mu) != 0) >= 8
    plain = random_phantom_setup(np.random.default_rng(9), layered_probability=0.0)
    assert not any(p.name == "barium layer" for p in plain.primitives)
    img = anatomy.line_integrals(View.from_gantry(-45.0, **SMALL))
    assert img.min() >= 0.0 and 2.0 < np.median(img) < 12.0


def test_mixed_kind_follows_the_papers_animal_to_phantom_ratio():
    assert MIXED_ABDOMEN_PROBABILITY == pytest.approx(156 / 212)
    kinds = []
    for seed in range(30):
        expected = "abdomen" if np.random.default_rng(seed).random() < 156 / 212 else "phantom"
        kind = random_background(np.random.default_rng(seed), "mixed").kind
        assert kind == expected
        kinds.append(kind)
    assert set(kinds) == {"abdomen", "phantom"}


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
    with pytest.raises(ValueError, match="semi_axes_mm"):
        Ellipsoid([0, 0, 0], [10.0, -5.0, 3.0])
    with pytest.raises(ValueError, match="half_sizes_mm"):
        Box([0, 0, 0], [10.0, 0.0, 3.0])
    with pytest.raises(ValueError, match="R must be a proper rotation"):
        Ellipsoid([0, 0, 0], [1.0, 1.0, 1.0], R=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="R must be a proper rotation"):
        Box([0, 0, 0], [1.0, 1.0, 1.0], R=np.eye(3) * 2.0)
    with pytest.raises(ValueError, match="mu_per_mm"):
        Ellipsoid([0, 0, 0], [1.0, 1.0, 1.0], mu_per_mm=float("nan"))
    with pytest.raises(ValueError, match="center_mm"):
        Box([0, 0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="keep must be a convex"):
        Difference(Difference(Box([0, 0, 0], [1, 1, 1]), Box([0, 0, 0], [1, 1, 1])), Box([0, 0, 0], [1, 1, 1]))
    with pytest.raises(ValueError, match="kind must be 'abdomen', 'phantom' or 'mixed', got 'pig'"):
        random_background(np.random.default_rng(0), "pig")
    with pytest.raises(TypeError, match="rng"):
        random_abdomen(42)
    with pytest.raises(ValueError, match="unknown AbdomenParams field"):
        random_abdomen(np.random.default_rng(0), body_widht_mm=(300, 350))
    with pytest.raises(ValueError, match="fat_mm"):
        AbdomenParams(fat_mm=(30.0, 10.0))
    with pytest.raises(ValueError, match="oversample"):
        Anatomy(()).line_integrals(View.from_gantry(0.0, **SMALL), oversample=0)
    with pytest.raises(ValueError, match="primitives\\[0\\]"):
        Anatomy(("sphere",))
