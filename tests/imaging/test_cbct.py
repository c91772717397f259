"""Tests of histostudy.imaging.cbct: the layered phantom (§II-D.1), the CBCT simulation and the
target (§II-D)."""

import numpy as np
import pytest

from histostudy.geometry import invert_transform, make_transform, rotation_about_axis, transform_points
from histostudy.imaging import Volume, cbct

SPEC = cbct.PhantomSpec()


# --- Phantom ----------------------------------------------------------------------------------


def test_phantom_layers_thickness_alternation_and_values():
    # margin 4.75 mm puts voxel centres 0.25 mm off every layer boundary
    vol = cbct.phantom_volume(SPEC, spacing_mm=0.5, margin_mm=4.75, supersample=1)
    x, y, z = vol.axes_mm()
    ix, iy = np.argmin(np.abs(x)), np.argmin(np.abs(y))
    profile = vol.data[:, iy, ix]
    inside = np.abs(z) < 25.0
    assert np.all(profile[~inside] == SPEC.water_hu)
    vals = profile[inside]
    assert set(np.unique(vals)) == {SPEC.agarose_hu, SPEC.barium_hu}
    assert vals[0] == SPEC.agarose_hu  # first_layer at the bottom face
    change = np.nonzero(np.diff(vals))[0] + 1
    runs = np.diff(np.concatenate([[0], change, [len(vals)]])) * 0.5  # mm
    assert np.allclose(runs[:-1], 4.0)  # 12 full layers of 4 mm ...
    assert np.isclose(runs[-1], 50.0 - 12 * 4.0)  # ... and the 2 mm remainder of a 50 mm cube
    run_vals = vals[np.concatenate([[0], change])]
    assert np.all(run_vals[0::2] == SPEC.agarose_hu) and np.all(run_vals[1::2] == SPEC.barium_hu)
    # the cube is 50 mm wide along x as well (count voxels inside along a row)
    row = vol.data[np.argmin(np.abs(z - 1.0)), iy, :]
    assert np.count_nonzero(row != SPEC.water_hu) * 0.5 == 50.0


def test_phantom_supersampling_gives_partial_volume_on_a_layer_boundary():
    # 1 mm voxels whose centres sit exactly on the boundaries z = -21, -17, ...: half of each layer
    vol = cbct.phantom_volume(SPEC, spacing_mm=1.0, margin_mm=5.0, supersample=2)
    x, y, z = vol.axes_mm()
    k = int(np.argmin(np.abs(z + 21.0)))
    assert np.isclose(z[k], -21.0)
    assert np.isclose(vol.data[k, len(y) // 2, len(x) // 2], 0.5 * (SPEC.agarose_hu + SPEC.barium_hu))
    assert np.isclose(vol.data[k - 2, len(y) // 2, len(x) // 2], SPEC.agarose_hu)


def test_phantom_pose_moves_layers_with_the_phantom():
    T = make_transform(rotation_about_axis([1, 2, 0.5], 0.7), [3.0, -4.0, 2.0])
    rng = np.random.default_rng(3)
    local = rng.uniform(-30, 30, size=(500, 3))
    world = transform_points(T, local)
    got = cbct.phantom_values(world, SPEC, T)
    expected = np.where(np.all(np.abs(local) <= 25, axis=1), SPEC.layer_values(local[:, 2]), SPEC.water_hu)
    assert np.array_equal(got, expected)
    assert np.isclose(SPEC.layer_contrast_hu, 420.0)


def test_phantom_volume_agrees_with_pointwise_values_for_a_rotated_pose():
    T = make_transform(rotation_about_axis([1, 2, 0.5], 0.7), [3.0, -4.0, 2.0])
    vol = cbct.phantom_volume(SPEC, T, spacing_mm=1.3, margin_mm=2.0, supersample=1)
    expected = cbct.phantom_values(vol.world_points().reshape(-1, 3), SPEC, T).reshape(vol.data.shape)
    assert np.array_equal(vol.data, expected.astype(np.float32))
    inside = cbct.phantom_mask(vol, SPEC, T)
    assert np.array_equal(inside, vol.data != SPEC.water_hu)  # water is 0 HU, both layers are not


def test_phantom_spec_rejects_bad_values():
    with pytest.raises(ValueError, match="layer_thickness_mm"):
        cbct.PhantomSpec(layer_thickness_mm=0.0)
    with pytest.raises(ValueError, match="first_layer"):
        cbct.PhantomSpec(first_layer="lead")
    with pytest.raises(ValueError, match="barium_hu"):
        cbct.PhantomSpec(barium_hu=float("nan"))


# --- CBCT simulation --------------------------------------------------------------------------


def test_simulate_cbct_is_seeded_and_has_the_requested_noise():
    vol = Volume(np.zeros((30, 30, 30)), 1.0)
    a = cbct.simulate_cbct(vol, 5, blur_sigma_mm=0.5, noise_sd_hu=25.0)
    b = cbct.simulate_cbct(vol, np.random.default_rng(5), blur_sigma_mm=0.5, noise_sd_hu=25.0)
    c = cbct.simulate_cbct(vol, 6, blur_sigma_mm=0.5, noise_sd_hu=25.0)
    assert np.array_equal(a.data, b.data)
    assert not np.array_equal(a.data, c.data)
    assert abs(a.data.std() - 25.0) < 1.0  # 27000 samples: sd of the sd ~ 0.1
    with pytest.raises(ValueError, match="noise_sd_hu"):
        cbct.simulate_cbct(vol, 0, noise_sd_hu=-1.0)


def test_simulate_cbct_blur_has_the_requested_sigma():
    data = np.zeros((41, 41, 41))
    data[20, 20, 20] = 1.0
    vol = Volume(data, 0.5)
    out = cbct.simulate_cbct(vol, 0, blur_sigma_mm=1.5, noise_sd_hu=0.0).data.astype(np.float64)
    x = vol.axes_mm()[0] - vol.axes_mm()[0][20]
    for axis in range(3):
        other = tuple(a for a in range(3) if a != axis)
        marginal = out.sum(axis=other)
        marginal /= marginal.sum()
        assert np.isclose(np.sqrt(np.sum(marginal * x**2)), 1.5, rtol=0.02)


def test_simulate_cbct_resamples_onto_the_requested_voxels():
    vol = Volume.from_bounds((-10, -10, -10), (10, 10, 10), 0.5)
    vol = vol.with_data(vol.world_points() @ np.array([1.0, -2.0, 0.5]))
    out = cbct.simulate_cbct(vol, 0, blur_sigma_mm=0.0, noise_sd_hu=0.0, voxel_mm=(1.0, 2.0, 1.0))
    assert np.allclose(out.spacing_mm, [1.0, 2.0, 1.0])
    assert np.allclose(out.data, out.world_points() @ np.array([1.0, -2.0, 0.5]), atol=1e-4)


# --- Target -----------------------------------------------------------------------------------


def test_check_target_accepts_inside_and_names_outside():
    T = make_transform(rotation_about_axis([0, 0, 1], np.pi / 4), [5.0, 0.0, 0.0])
    assert np.allclose(cbct.check_target([5.0, 1.0, 2.0], SPEC, T), [5.0, 1.0, 2.0])
    with pytest.raises(ValueError, match=r"target_mm=.*outside the phantom"):
        cbct.check_target([5.0 + 40.0, 0.0, 0.0], SPEC, T)
    # inside the cube but too close to a face for a 10 mm margin
    with pytest.raises(ValueError, match="outside the phantom"):
        cbct.check_target([5.0, 0.0, 20.0], SPEC, T, margin_mm=10.0)
    vol = Volume.from_bounds((-5, -5, -5), (4, 4, 4), 1.0)  # x = 5 is beyond its last voxel
    assert np.allclose(cbct.check_target([4.0, 1.0, 2.0], SPEC, T, volume=vol), [4.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="outside the CBCT volume"):
        cbct.check_target([5.0, 1.0, 2.0], SPEC, T, volume=vol)
    with pytest.raises(ValueError, match="target_mm"):
        cbct.check_target([1.0, 2.0], SPEC, T)


def test_random_target_stays_away_from_the_faces_and_is_seeded():
    T = make_transform(rotation_about_axis([1, 1, 1], 0.4), [1.0, 2.0, 3.0])
    targets = np.array([cbct.random_target(s, SPEC, T, border_mm=15.0) for s in range(200)])
    local = transform_points(invert_transform(T), targets)
    assert np.all(np.abs(local) <= 10.0 + 1e-9)
    assert np.abs(local).max() > 9.0  # uses the whole allowed cube
    assert np.array_equal(cbct.random_target(7, SPEC, T), cbct.random_target(7, SPEC, T))
    with pytest.raises(ValueError, match="border_mm"):
        cbct.random_target(0, SPEC, T, border_mm=30.0)
