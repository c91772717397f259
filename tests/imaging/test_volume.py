"""Tests of histostudy.imaging.volume: the Volume (§II-A), its spacing, index order and world <-> voxel
mapping, and its trilinear sampling."""

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from histostudy.imaging import Volume


def test_volume_refuses_missing_or_bad_spacing():
    with pytest.raises(ValueError, match="without spacing"):
        Volume(np.zeros((2, 3, 4)), None)
    for bad in (0.0, -1.0, (1.0, 0.0, 1.0), (1.0, np.nan, 1.0)):
        with pytest.raises(ValueError, match="spacing_mm"):
            Volume(np.zeros((2, 3, 4)), bad)
    with pytest.raises(ValueError, match="3-D"):
        Volume(np.zeros((3, 4)), 1.0)
    with pytest.raises(ValueError, match="upper_mm"):
        Volume.from_bounds((0, 0, 0), (1, -1, 1), 0.5)


def test_volume_index_order_and_world_voxel_round_trip():
    data = np.zeros((2, 3, 4))  # [z, y, x]
    vol = Volume(data, (0.5, 1.0, 2.0), origin_mm=(10.0, -5.0, 3.0))
    assert vol.shape_xyz == (4, 3, 2)
    assert np.allclose(vol.upper_mm, [10.0 + 3 * 0.5, -5.0 + 2 * 1.0, 3.0 + 1 * 2.0])
    rng = np.random.default_rng(0)
    pts = rng.uniform(-20, 20, size=(50, 3))
    assert np.allclose(vol.voxel_to_world(vol.world_to_voxel(pts)), pts)
    # world_points puts voxel [iz, iy, ix] at origin + (ix, iy, iz) * spacing
    wp = vol.world_points()
    assert np.allclose(wp[1, 2, 3], [10.0 + 3 * 0.5, -5.0 + 2 * 1.0, 3.0 + 1 * 2.0])


def test_trilinear_sampling_reproduces_a_trilinear_field_exactly():
    # Trilinear interpolation is exact for any function a + bx + cy + dz + exy + fyz + gxz + hxyz.
    vol = Volume.from_bounds((-4.0, -3.0, -2.0), (4.0, 3.0, 6.0), (0.7, 0.5, 1.1))
    wp = vol.world_points()
    def f(p):
        return 1 + 2 * p[..., 0] - 3 * p[..., 1] + 0.5 * p[..., 2] + 0.01 * p[..., 0] * p[..., 1] * p[..., 2]
    vol = vol.with_data(f(wp))
    rng = np.random.default_rng(1)
    pts = rng.uniform(vol.lower_mm, vol.upper_mm, size=(200, 3))
    assert np.allclose(vol.sample(pts), f(pts), atol=1e-3)  # float32 storage
    assert np.isnan(vol.sample([[100.0, 0.0, 0.0]])[0])
    assert vol.sample([[100.0, 0.0, 0.0]], outside=-7.0)[0] == -7.0


def test_trilinear_sampling_matches_scipy_reference_on_random_data():
    rng = np.random.default_rng(2)
    vol = Volume(rng.normal(size=(5, 6, 7)), (1.0, 0.5, 2.0), origin_mm=(1.0, 2.0, 3.0))
    x, y, z = vol.axes_mm()
    ref = RegularGridInterpolator((z, y, x), vol.data.astype(np.float64), method="linear")
    pts = rng.uniform(vol.lower_mm, vol.upper_mm, size=(100, 3))
    assert np.allclose(vol.sample(pts), ref(pts[:, ::-1]), atol=1e-10)
