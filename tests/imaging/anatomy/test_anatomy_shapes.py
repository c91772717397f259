"""Tests of histostudy.imaging.anatomy._shapes and _csg: analytic chords of the solids and their
composites against brute-force point sampling."""

import numpy as np
import pytest

from histostudy.geometry import rotation_about_axis
from histostudy.geometry.transforms import random_rotation
from histostudy.imaging.anatomy._csg import Difference, Intersection
from histostudy.imaging.anatomy._shapes import Box, Ellipsoid, EllipticCylinder


def numeric_chord(contains, origin, direction, t_range=(0.0, 1200.0), dt=0.01):
    """Independent reference: midpoint-rule length of the ray inside a solid, by point tests.

    ``t_range`` (mm along the ray) must cover the solid; the tests' solids lie 500-1000 mm away.
    """
    t = np.arange(t_range[0] + dt / 2.0, t_range[1], dt)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    pts = np.asarray(origin, float) + t[:, None] * d
    return float(contains(pts).sum() * dt)


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
