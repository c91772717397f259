"""Tests of histostudy.treatment.bubble_cloud: the 3x3x6 mm bubble clouds, the post-treatment phantom
(§II-D.1) and the whole chain from plan to the zone found in the post-treatment CBCT."""

import numpy as np
import pytest
from treatment_setup import R_CT, robot_zone_and_calibration

from histostudy.geometry import invert_transform, make_transform, rotation_about_axis
from histostudy.imaging import Volume, cbct
from histostudy.treatment import TreatmentZone, execute_treatment, plan_treatment, segment_treatment_zone
from histostudy.treatment.bubble_cloud import BUBBLE_CLOUD_SIZE_MM, bubble_cloud_mask, post_treatment_phantom


def test_bubble_cloud_is_a_3x3x6_ellipsoid_along_the_propagation_axis():
    R = rotation_about_axis([0.3, -1.0, 0.6], 1.1)
    T = make_transform(R, [0.4, -0.3, 0.2])
    focal, offset = np.array([0.2, 0.0, -0.5]), np.array([0.3, -0.4, 0.8])
    vol = Volume.from_bounds((-6, -6, -6), (6, 6, 6), 0.2)
    mask = bubble_cloud_mask(vol, T, focal_point_mm=focal, offset_mm=offset)
    pts = vol.world_points()[mask]
    centre = T[:3, :3] @ (focal + offset) + T[:3, 3]
    assert np.allclose(pts.mean(axis=0), centre, atol=0.05)
    assert abs(len(pts) * 0.2**3 / (4 / 3 * np.pi * 1.5 * 1.5 * 3.0) - 1) < 0.03
    # the principal axis is the transducer's z (propagation)
    w, v = np.linalg.eigh(np.cov((pts - centre).T))
    assert abs(v[:, -1] @ R[:, 2]) > 0.999
    # extents along LR, TB, depth: 3, 3, 6 mm (within a voxel)
    proj = (pts - centre) @ R
    assert np.allclose(proj.max(axis=0) - proj.min(axis=0), [3.0, 3.0, 6.0], atol=0.4)
    # union of two disjoint clouds
    T2 = T.copy()
    T2[:3, 3] += 10 * R[:, 0]
    vol2 = Volume.from_bounds((-15, -15, -15), (15, 15, 15), 0.5)
    one = bubble_cloud_mask(vol2, T).sum()
    assert bubble_cloud_mask(vol2, np.stack([T, T2])).sum() == one + bubble_cloud_mask(vol2, T2).sum()
    with pytest.raises(ValueError, match="T_carm_transducer"):
        bubble_cloud_mask(vol2, 2 * np.eye(4))


def test_post_treatment_phantom_mixes_only_the_treated_phantom():
    spec = cbct.PhantomSpec()
    truth = cbct.phantom_volume(spec, spacing_mm=1.0, margin_mm=3.0, supersample=1)
    roi = cbct.phantom_mask(truth, spec)
    treated = TreatmentZone([0.0, 0.0, 22.0], 20.0).mask(truth)  # pokes out of the top face
    post = post_treatment_phantom(truth, treated, roi)
    region = treated & roi
    assert np.allclose(post.data[region], truth.data[region].mean())
    assert np.array_equal(post.data[~region], truth.data[~region])
    assert np.all(post.data[treated & ~roi] == spec.water_hu)
    # a zone spanning many layers mixes to near the mid value
    post2 = post_treatment_phantom(truth, TreatmentZone([0, 0, 0], 20.0).mask(truth), roi)
    mid = 0.5 * (spec.agarose_hu + spec.barium_hu)
    assert abs(post2.data[25 + 3, 25 + 3, 25 + 3] - mid) < 0.1 * spec.layer_contrast_hu
    with pytest.raises(ValueError, match="treated_mask"):
        post_treatment_phantom(truth, treated[1:], roi)


def test_end_to_end_treatment_is_found_where_the_clouds_were(tmp_path):
    """Plan -> robot -> bubble clouds (with an offset) -> mixed phantom -> CBCT -> segmentation."""
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration(seed=4)
    half_cloud = 0.5 * np.array(BUBBLE_CLOUD_SIZE_MM)
    # (2, 2, 2) mm is the coarsest cubic lattice whose 3x3x6 clouds still cover each cell
    plan = plan_treatment(zone, 2.0, pulses_per_point=10, axes=R_CT, inset_mm=half_cloud)
    run = execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.json")
    T_carm_tcp = np.einsum("ij,njk->nik", invert_transform(T_base_carm), run.reached_T_base_tcp)
    spec = cbct.PhantomSpec()
    # water beyond a segmentation window (8 mm) around the phantom: the noise level is measured there
    truth = cbct.phantom_volume(spec, spacing_mm=1.0, margin_mm=12.0, supersample=2)
    offset = np.array([0.6, -0.4, 1.2])  # bubble cloud off the geometric focal point (§IV)
    clouds = bubble_cloud_mask(truth, T_carm_tcp, offset_mm=offset)
    post = post_treatment_phantom(truth, clouds, cbct.phantom_mask(truth, spec))
    ct = cbct.simulate_cbct(post, 9, blur_sigma_mm=0.5, noise_sd_hu=20.0)
    seg = segment_treatment_zone(ct, cbct.phantom_mask(ct, spec))
    expected_centre = zone.centre_mm + R_CT @ offset
    assert np.linalg.norm(seg.centroid_mm - expected_centre) < 0.5
    assert np.linalg.norm(seg.centroid_mm - zone.centre_mm) > 1.0  # the offset is seen
    assert abs(seg.sphere_radius_mm - zone.radius_mm) < 1.0
    # the zone's size is that of what was treated: the union of clouds, whose volume falls short
    # of the planned sphere's (scalloped surface between the cloud tips)
    treated = clouds & cbct.phantom_mask(truth, spec)
    treated_radius = (3.0 * treated.sum() * truth.voxel_volume_mm3 / (4.0 * np.pi)) ** (1.0 / 3.0)
    assert abs(seg.equivalent_radius_mm - treated_radius) < 0.3
    # along one line the scallops count in full: at the depth poles the 6 mm clouds on a 2 mm
    # lattice stand up to 2 mm proud of the valleys between them, which the boundary window
    # (4 mm) averages, so the radius along depth reads up to ~1.3 mm short of the cloud tips
    assert np.all(np.abs(seg.radii_along(R_CT) - zone.radius_mm) < 1.5)
