"""Tests of histostudy.treatment.zone: the treatment zone (§II-D) and its segmentation in the
post-treatment CBCT (§II-E.3-4) against known spheres."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import Volume, cbct
from histostudy.treatment import TreatmentZone, segment_treatment_zone
from histostudy.treatment.bubble_cloud import post_treatment_phantom

SPEC = cbct.PhantomSpec()


# --- Treatment zone ---------------------------------------------------------------------------


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
