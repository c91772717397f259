"""Tests of histostudy.imaging.cbct: the Volume, the layered phantom (§II-D.1), the CBCT simulation, the
target and zone (§II-D), and the zone segmentation (§II-E.3-4) against known spheres."""

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from histostudy.geometry import invert_transform, make_transform, rotation_about_axis, transform_points
from histostudy.imaging import cbct
from histostudy.imaging import Volume
from histostudy.treatment import TreatmentZone, segment_treatment_zone
from histostudy.treatment import post_treatment_phantom

SPEC = cbct.PhantomSpec()


# --- Volume -----------------------------------------------------------------------------------


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
    f = lambda p: 1 + 2 * p[..., 0] - 3 * p[..., 1] + 0.5 * p[..., 2] + 0.01 * p[..., 0] * p[..., 1] * p[..., 2]
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


# --- Target and zone --------------------------------------------------------------------------


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


def test_treatment_zone_margin_points_and_mask():
    R = rotation_about_axis([0, 1, 1], 1.0)
    zone = TreatmentZone([1.0, 2.0, 3.0], 25.0)
    m = zone.margin_points(R)
    assert np.allclose(np.linalg.norm(m - zone.centre_mm, axis=1), 12.5)
    assert np.allclose(m[0] - zone.centre_mm, 12.5 * R[:, 0]) and np.allclose(m[5] - zone.centre_mm, -12.5 * R[:, 2])
    vol = Volume.from_bounds((-15, -15, -15), (15, 15, 15), 0.5)
    assert abs(zone.mask(vol).sum() * 0.125 / (4 / 3 * np.pi * 12.5**3) - 1) < 0.01
    for bad in (0.0, -20.0, float("inf")):
        with pytest.raises(ValueError, match="diameter_mm"):
            TreatmentZone([0, 0, 0], bad)


# --- Zone segmentation ------------------------------------------------------------------------

T_PHANTOM = make_transform(rotation_about_axis([1, 1, 0], 0.3), [2.0, -1.0, 3.0])


@pytest.fixture(scope="module")
def truth():
    """The rotated phantom at 0.5 mm (the 'true' attenuation)."""
    return cbct.phantom_volume(SPEC, T_PHANTOM, spacing_mm=0.5, margin_mm=4.0, supersample=1)


def _treated_cbct(truth, zone, seed, blur, noise):
    roi = cbct.phantom_mask(truth, SPEC, T_PHANTOM)
    post = post_treatment_phantom(truth, zone.mask(truth), roi)
    ct = cbct.simulate_cbct(post, seed, blur_sigma_mm=blur, noise_sd_hu=noise, voxel_mm=1.0)
    return ct, cbct.phantom_mask(ct, SPEC, T_PHANTOM)


@pytest.mark.parametrize(
    "centre, diameter, blur, noise",
    [
        ((1.3, -0.7, 2.2), 20.0, 0.0, 0.0),
        ((1.3, -0.7, 2.2), 20.0, 0.5, 20.0),
        ((4.1, 2.9, 0.4), 25.0, 1.0, 40.0),
        ((-0.6, 1.7, 4.9), 20.0, 1.5, 80.0),
    ],
)
def test_segmentation_recovers_a_known_sphere(truth, centre, diameter, blur, noise):
    zone = TreatmentZone(np.array(centre), diameter)
    ct, roi = _treated_cbct(truth, zone, seed=11, blur=blur, noise=noise)
    seg = segment_treatment_zone(ct, roi)
    voxel = 1.0
    assert np.linalg.norm(seg.centroid_mm - zone.centre_mm) < 0.5 * voxel
    assert np.linalg.norm(seg.sphere_centre_mm - zone.centre_mm) < 0.5 * voxel
    assert abs(seg.sphere_radius_mm - zone.radius_mm) < voxel
    assert abs(seg.equivalent_radius_mm - zone.radius_mm) < voxel
    R = rotation_about_axis([0.2, -1, 0.4], 0.9)  # some transducer orientation
    assert np.all(np.abs(seg.radii_along(R) - zone.radius_mm) < voxel)
    # the true margin points lie on the true surface: within a voxel of the segmented one
    assert np.all(seg.distance_to_surface(zone.margin_points(R)) < voxel)
    # the mask is one solid blob inside the phantom
    assert np.all(roi[seg.mask])
    assert seg.layered_variance > 4 * seg.homogeneous_variance


def test_segmentation_boundary_is_unbiased_on_curved_zones(truth):
    """The boundary stage removes the window's curvature bias: at the study's CBCT settings
    (0.5 mm blur, 20 HU) the radius comes out within a fraction of a voxel, unlike the coarse
    stage's local-variance boundary alone, which reads 20-25 mm spheres about 0.3 mm small."""
    R = rotation_about_axis([0.2, -1, 0.4], 0.9)
    errors, coarse_errors = [], []
    for k, (centre, diameter) in enumerate([((1.3, -0.7, 2.2), 20.0), ((-2.1, 0.8, -1.4), 25.0),
                                            ((0.4, 2.6, 0.9), 20.0), ((2.2, -1.9, -2.8), 25.0)]):
        zone = TreatmentZone(np.array(centre), diameter)
        ct, roi = _treated_cbct(truth, zone, seed=20 + k, blur=0.5, noise=20.0)
        seg = segment_treatment_zone(ct, roi)
        errors.append([seg.sphere_radius_mm - zone.radius_mm, *(seg.radii_along(R) - zone.radius_mm)])
        assert 0.3 < seg.treated_fraction_threshold < 0.5  # convex: below the flat boundary's 1/2
        coarse = segment_treatment_zone(ct, roi, boundary_window_mm=8.0, n_refinements=0)
        coarse_errors.append(coarse.sphere_radius_mm - zone.radius_mm)
    errors = np.array(errors)
    assert abs(errors[:, 0].mean()) < 0.15
    assert np.all(np.abs(errors[:, 1:]) < 0.4)
    # a layer-period window at the flat-boundary threshold reads the same spheres small
    assert np.mean(coarse_errors) < -0.25


def test_segmentation_distance_to_surface_is_signed_on_request(truth):
    zone = TreatmentZone(np.array([1.3, -0.7, 2.2]), 20.0)
    ct, roi = _treated_cbct(truth, zone, seed=1, blur=0.5, noise=20.0)
    seg = segment_treatment_zone(ct, roi)
    c, r = seg.sphere_centre_mm, seg.sphere_radius_mm
    pts = np.array([c + [r + 2.0, 0, 0], c + [0, r - 3.0, 0]])
    assert np.allclose(seg.distance_to_surface(pts, signed=True), [2.0, -3.0])
    assert np.allclose(seg.distance_to_surface(pts), [2.0, 3.0])


def test_segmentation_without_water_needs_the_noise_variance(truth):
    zone = TreatmentZone(np.array([1.3, -0.7, 2.2]), 20.0)
    ct, roi = _treated_cbct(truth, zone, seed=2, blur=0.5, noise=20.0)
    full = segment_treatment_zone(ct, roi)
    # crop to a box around the zone: too little water left to measure the noise in
    c = np.round(ct.world_to_voxel(zone.centre_mm)[0]).astype(int)
    sl = tuple(slice(c[a] - 22, c[a] + 23) for a in (2, 1, 0))
    crop = Volume(ct.data[sl], ct.spacing_mm, ct.voxel_to_world([[c[0] - 22, c[1] - 22, c[2] - 22]])[0])
    inside = cbct.phantom_mask(crop, SPEC, T_PHANTOM)
    with pytest.raises(ValueError, match="noise_variance"):
        segment_treatment_zone(crop, inside)
    seg = segment_treatment_zone(crop, inside, noise_variance=full.homogeneous_variance)
    assert np.linalg.norm(seg.centroid_mm - full.centroid_mm) < 0.1
    assert abs(seg.sphere_radius_mm - full.sphere_radius_mm) < 0.1


def test_segmentation_rejects_bad_inputs(truth):
    ct = Volume(np.zeros((20, 20, 20)), 1.0)
    with pytest.raises(ValueError, match="roi_mask"):
        segment_treatment_zone(ct, np.ones((5, 5, 5), bool))
    with pytest.raises(ValueError, match="window_mm"):
        segment_treatment_zone(ct, np.ones((20, 20, 20), bool), window_mm=0.0)
    with pytest.raises(TypeError, match="Volume"):
        segment_treatment_zone(np.zeros((20, 20, 20)), np.ones((20, 20, 20), bool))
    # a homogeneous volume has no layer texture to contrast the zone against
    roi = np.zeros((20, 20, 20), bool)
    roi[4:16, 4:16, 4:16] = True
    with pytest.raises(ValueError, match="no layer texture|too few|too small"):
        segment_treatment_zone(ct, roi, window_mm=3.0)
    with pytest.raises(ValueError, match="boundary_window_mm"):
        segment_treatment_zone(ct, roi, boundary_window_mm=float("nan"))
    with pytest.raises(ValueError, match="n_refinements"):
        segment_treatment_zone(ct, roi, n_refinements=-1)
