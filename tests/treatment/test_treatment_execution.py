"""Tests of histostudy.treatment: the plan (§II-D), execution with a resumable journal on the
simulated UR5e, the bubble clouds (3x3x6 mm) and the post-treatment phantom (§II-D.1)."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from histostudy.geometry import invert_transform, make_transform, rotation_about_axis, transform_points
from histostudy.imaging import cbct
from histostudy.imaging import Volume
from histostudy.treatment import TreatmentZone, segment_treatment_zone
from histostudy.robot import FaultPlan, RobotConnectionError, SimulatedUR5e
from histostudy.treatment import plan as tr

R_CT = rotation_about_axis([1.0, 0.3, 0.0], 2.6)  # a transducer orientation in the C-arm frame


def _sphere_samples(centre, radius, step=0.5):
    g = np.arange(-radius, radius + step / 2, step)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    p = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return centre + p[np.linalg.norm(p, axis=1) <= radius]


# --- plan -------------------------------------------------------------------------------------


@pytest.mark.parametrize("diameter, spacing", [(20.0, 2.0), (25.0, 3.0), (20.0, 4.0)])
def test_plan_points_inside_on_the_lattice_and_covering_the_sphere(diameter, spacing):
    zone = TreatmentZone([1.0, -2.0, 3.0], diameter)
    plan = tr.plan_treatment(zone, spacing, pulses_per_point=20, axes=R_CT)
    rel = plan.points_mm - zone.centre_mm
    assert np.all(np.linalg.norm(rel, axis=1) <= zone.radius_mm + 1e-9)
    # the lattice points sit at integer multiples of the spacing along the plan's axes ...
    lat = plan.points_mm[~plan.on_rim]
    coords = (lat - zone.centre_mm) @ R_CT / spacing
    assert np.allclose(coords, np.round(coords), atol=1e-9)
    assert np.array_equal(np.round(coords).astype(int), plan.lattice_index[~plan.on_rim])
    # ... with the requested spacing between nearest neighbours
    d, _ = cKDTree(lat).query(lat, k=2)
    assert np.allclose(d[:, 1], spacing)
    # rim points lie on the sphere
    assert np.allclose(np.linalg.norm(plan.points_mm[plan.on_rim] - zone.centre_mm, axis=1), zone.radius_mm)
    # every point of the sphere is within spacing * sqrt(3) / 2 of a focal point
    dist, _ = cKDTree(plan.points_mm).query(_sphere_samples(zone.centre_mm, zone.radius_mm))
    assert np.isclose(plan.covering_radius_mm, spacing * np.sqrt(3) / 2)
    assert dist.max() <= plan.covering_radius_mm + 1e-9
    assert plan.pulses_per_point == 20 and len(np.unique(plan.points_mm, axis=0)) == len(plan)


def test_plan_with_inset_fills_the_inner_ellipsoid_with_anisotropic_spacing():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    inset = np.array([1.5, 1.5, 3.0])
    plan = tr.plan_treatment(zone, (1.5, 2.0, 3.0), pulses_per_point=5, axes=R_CT, inset_mm=inset)
    semi = zone.radius_mm - inset
    local = plan.points_mm @ R_CT
    assert np.all(np.sum((local / semi) ** 2, axis=1) <= 1 + 1e-9)
    assert np.allclose(np.sum((local[plan.on_rim] / semi) ** 2, axis=1), 1.0, atol=1e-9)
    # coverage of the ellipsoid: sample it and check the covering radius |spacing| / 2
    g = _sphere_samples(np.zeros(3), 1.0, step=0.05) * semi  # unit ball scaled to the ellipsoid
    dist, _ = cKDTree(local).query(g)
    assert dist.max() <= 0.5 * np.linalg.norm([1.5, 2.0, 3.0]) + 1e-9


def test_plan_order_is_deep_first_and_serpentine():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    plan = tr.plan_treatment(zone, 2.0, axes=R_CT)
    ijk = plan.lattice_index
    assert np.all(np.diff(ijk[:, 2]) >= 0)  # layer by layer along the transducer's +z: deepest first
    depth_coord = plan.points_mm @ R_CT[:, 2]
    layer_means = [depth_coord[ijk[:, 2] == k].mean() for k in np.unique(ijk[:, 2])]
    assert np.all(np.diff(layer_means) > 1.0)  # along +z of the transducer: from the deepest layer up
    assert np.argmin(layer_means) == 0 and len(layer_means) == 11
    # rows: consecutive points in a row are lattice neighbours, and rows alternate direction
    same_row = (np.diff(ijk[:, 2]) == 0) & (np.diff(ijk[:, 1]) == 0)
    steps = np.diff(ijk[:, 0])[same_row]
    assert np.all(np.abs(steps) == 1)
    row_id = np.concatenate([[0], np.cumsum(~same_row)])
    # the r-th row (counting one-point rows too) runs along +x for even r, along -x for odd r
    for r in np.unique(row_id):
        if np.sum(row_id == r) > 1:
            assert np.sign(np.diff(ijk[row_id == r, 0])[0]) == (1 if r % 2 == 0 else -1)
    # a serpentine path is short: no jump longer than a few spacings
    assert np.linalg.norm(np.diff(plan.points_mm, axis=0), axis=1).max() < 4 * 2.0 * np.sqrt(3)


def test_plan_rejects_bad_parameters():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    for bad in (0.0, -1.0, (1.0, 0.0, 1.0)):
        with pytest.raises(ValueError, match="spacing_mm"):
            tr.plan_treatment(zone, bad)
    with pytest.raises(ValueError, match="pulses_per_point"):
        tr.plan_treatment(zone, 2.0, pulses_per_point=0)
    with pytest.raises(ValueError, match="inset_mm"):
        tr.plan_treatment(zone, 2.0, inset_mm=(1.0, 1.0, 10.0))
    with pytest.raises(TypeError, match="TreatmentZone"):
        tr.plan_treatment([0, 0, 0], 2.0)


# --- execution and journal --------------------------------------------------------------------


def _setup(seed=1):
    """A robot, and a calibration that puts the zone centre at the robot's home TCP position."""
    robot = SimulatedUR5e(seed)
    T_home = robot.tcp_pose()
    zone = TreatmentZone([1.0, -2.0, 0.5], 20.0)
    R_base_carm = T_home[:3, :3] @ R_CT.T  # the transducer's home orientation is R_CT in the C-arm
    T_base_carm = make_transform(R_base_carm, T_home[:3, 3] - R_base_carm @ zone.centre_mm)
    return robot, zone, T_base_carm, T_home[:3, :3]


def test_execution_commands_every_point_and_journals_reached_poses(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = _setup()
    plan = tr.plan_treatment(zone, 4.0, pulses_per_point=7, axes=R_CT)
    fired = []
    run = tr.execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.json", deliver=lambda i, n: fired.append((i, n)))
    assert run.completed and run.n_treated == len(plan) and run.resumed_at == 0
    assert fired == [(i, 7) for i in range(len(plan))]
    assert robot.state().moves_completed == len(plan)
    # commanded: the plan points mapped into the base frame, orientation fixed
    assert np.allclose(run.commanded_T_base_tcp[:, :3, 3], transform_points(T_base_carm, plan.points_mm))
    assert np.allclose(run.commanded_T_base_tcp[:, :3, :3], R_base_tcp)
    # reached: within the UR5e repeatability of the commanded position
    err = np.linalg.norm(run.reached_T_base_tcp[:, :3, 3] - run.commanded_T_base_tcp[:, :3, 3], axis=1)
    assert err.max() <= 0.03 + 1e-9 and err.max() > 0
    journal = json.loads((tmp_path / "j.json").read_text())
    assert journal["completed"] and len(journal["points"]) == len(plan)
    assert np.allclose(journal["points"][3]["reached_T_base_tcp"], run.reached_T_base_tcp[3])
    assert journal["plan_fingerprint"] == plan.fingerprint()
    # a completed journal makes a rerun do nothing
    robot2 = SimulatedUR5e(2)
    again = tr.execute_treatment(robot2, plan, T_base_carm, R_base_tcp, tmp_path / "j.json")
    assert again.completed and robot2.moves_planned == 0
    assert np.array_equal(again.reached_T_base_tcp, run.reached_T_base_tcp)


@pytest.mark.parametrize("faults, n_journaled", [
    (lambda k: FaultPlan(disconnect_after_moves=k), lambda k: k),  # move k done, then the link drops
    (lambda k: FaultPlan(disconnect_during_move=k), lambda k: k - 1),  # move k never finishes
])
def test_interrupted_treatment_resumes_without_repeating_or_skipping(tmp_path, faults, n_journaled):
    robot, zone, T_base_carm, R_base_tcp = _setup()
    plan = tr.plan_treatment(zone, 4.0, pulses_per_point=3, axes=R_CT)
    k = 17
    path = tmp_path / "journal.json"
    fired = []
    deliver = lambda i, n: fired.append(i)
    faulty = SimulatedUR5e(1, faults=faults(k))
    with pytest.raises(RobotConnectionError) as info:
        tr.execute_treatment(faulty, plan, T_base_carm, R_base_tcp, path, deliver=deliver)
    assert any("resume" in note for note in getattr(info.value, "__notes__", []))
    # the journal on disk is whole, valid JSON holding exactly the treated points; no temp files left
    journal = json.loads(path.read_text())
    assert [p["index"] for p in journal["points"]] == list(range(n_journaled(k)))
    assert not journal["completed"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["journal.json"]
    before = [p["reached_T_base_tcp"] for p in journal["points"]]
    partial = tr.TreatmentRun.load(path)
    assert partial.n_treated == n_journaled(k) and not partial.completed and partial.n_planned == len(plan)
    # a fresh robot with the same journal treats the rest
    fresh = SimulatedUR5e(2)
    run = tr.execute_treatment(fresh, plan, T_base_carm, R_base_tcp, path, deliver=deliver)
    assert run.completed and run.resumed_at == n_journaled(k)
    assert fresh.state().moves_completed == len(plan) - n_journaled(k)
    assert sorted(fired) == list(range(len(plan))) and len(set(fired)) == len(fired)  # once each
    assert np.array_equal(run.indices, np.arange(len(plan)))
    assert np.allclose(run.reached_T_base_tcp[: len(before)], np.array(before))  # history kept
    err = np.linalg.norm(run.reached_T_base_tcp[:, :3, 3] - run.commanded_T_base_tcp[:, :3, 3], axis=1)
    assert err.max() <= 0.03 + 1e-9


def test_a_failed_journal_write_leaves_the_previous_journal_whole(tmp_path, monkeypatch):
    import histostudy.core.io as hio

    robot, zone, T_base_carm, R_base_tcp = _setup()
    plan = tr.plan_treatment(zone, 5.0, axes=R_CT)
    path = tmp_path / "j.json"
    real_replace, calls = hio.os.replace, []

    def failing_replace(src, dst):  # the 6th write (header + 5 points) dies before the rename
        calls.append(dst)
        if len(calls) == 6:
            raise OSError("disk full")
        real_replace(src, dst)

    monkeypatch.setattr(hio.os, "replace", failing_replace)
    fired = []
    with pytest.raises(OSError, match="disk full"):
        tr.execute_treatment(robot, plan, T_base_carm, R_base_tcp, path, deliver=lambda i, n: fired.append(i))
    monkeypatch.setattr(hio.os, "replace", real_replace)
    journal = json.loads(path.read_text())  # the previous version, whole
    assert [p["index"] for p in journal["points"]] == [0, 1, 2, 3]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["j.json"]  # no temporary file left
    run = tr.execute_treatment(SimulatedUR5e(3), plan, T_base_carm, R_base_tcp, path, deliver=lambda i, n: fired.append(i))
    assert run.completed and run.resumed_at == 4
    # point 4 was fired but never journaled: the documented (only) way a point is fired twice
    assert sorted(fired) == sorted(list(range(len(plan))) + [4])


def test_journal_refuses_another_plan_or_calibration(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = _setup()
    plan = tr.plan_treatment(zone, 5.0, axes=R_CT)
    path = tmp_path / "j.json"
    with pytest.raises(RobotConnectionError):
        tr.execute_treatment(SimulatedUR5e(1, faults=FaultPlan(disconnect_after_moves=3)), plan, T_base_carm, R_base_tcp, path)
    other = tr.plan_treatment(zone, 4.0, axes=R_CT)
    with pytest.raises(ValueError, match="another plan"):
        tr.execute_treatment(robot, other, T_base_carm, R_base_tcp, path)
    shifted = T_base_carm.copy()
    shifted[0, 3] += 1.0
    with pytest.raises(ValueError, match="T_base_carm"):
        tr.execute_treatment(robot, plan, shifted, R_base_tcp, path)
    assert robot.moves_planned == 0  # refused before moving
    (tmp_path / "bad.json").write_text('{"format": "histostudy.treatment_journal", "points": [')
    with pytest.raises(ValueError, match="not valid JSON"):
        tr.execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "bad.json")


def test_execution_rejects_bad_arguments(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = _setup()
    plan = tr.plan_treatment(zone, 5.0)
    with pytest.raises(ValueError, match="T_base_carm"):
        tr.execute_treatment(robot, plan, np.eye(3), R_base_tcp, tmp_path / "j.json")
    with pytest.raises(ValueError, match="R_base_tcp"):
        tr.execute_treatment(robot, plan, T_base_carm, 2 * np.eye(3), tmp_path / "j.json")
    with pytest.raises(ValueError, match="speed_mm_s"):
        tr.execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.json", speed_mm_s=0.0)
    assert not (tmp_path / "j.json").exists()


# --- bubble clouds and the post-treatment phantom -----------------------------------------------


def test_bubble_cloud_is_a_3x3x6_ellipsoid_along_the_propagation_axis():
    R = rotation_about_axis([0.3, -1.0, 0.6], 1.1)
    T = make_transform(R, [0.4, -0.3, 0.2])
    focal, offset = np.array([0.2, 0.0, -0.5]), np.array([0.3, -0.4, 0.8])
    vol = Volume.from_bounds((-6, -6, -6), (6, 6, 6), 0.2)
    mask = tr.bubble_cloud_mask(vol, T, focal_point_mm=focal, offset_mm=offset)
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
    one = tr.bubble_cloud_mask(vol2, T).sum()
    assert tr.bubble_cloud_mask(vol2, np.stack([T, T2])).sum() == one + tr.bubble_cloud_mask(vol2, T2).sum()
    with pytest.raises(ValueError, match="T_carm_transducer"):
        tr.bubble_cloud_mask(vol2, 2 * np.eye(4))


def test_post_treatment_phantom_mixes_only_the_treated_phantom():
    spec = cbct.PhantomSpec()
    truth = cbct.phantom_volume(spec, spacing_mm=1.0, margin_mm=3.0, supersample=1)
    roi = cbct.phantom_mask(truth, spec)
    treated = TreatmentZone([0.0, 0.0, 22.0], 20.0).mask(truth)  # pokes out of the top face
    post = tr.post_treatment_phantom(truth, treated, roi)
    region = treated & roi
    assert np.allclose(post.data[region], truth.data[region].mean())
    assert np.array_equal(post.data[~region], truth.data[~region])
    assert np.all(post.data[treated & ~roi] == spec.water_hu)
    # a zone spanning many layers mixes to near the mid value
    post2 = tr.post_treatment_phantom(truth, TreatmentZone([0, 0, 0], 20.0).mask(truth), roi)
    mid = 0.5 * (spec.agarose_hu + spec.barium_hu)
    assert abs(post2.data[25 + 3, 25 + 3, 25 + 3] - mid) < 0.1 * spec.layer_contrast_hu
    with pytest.raises(ValueError, match="treated_mask"):
        tr.post_treatment_phantom(truth, treated[1:], roi)


def test_end_to_end_treatment_is_found_where_the_clouds_were(tmp_path):
    """Plan -> robot -> bubble clouds (with an offset) -> mixed phantom -> CBCT -> segmentation."""
    robot, zone, T_base_carm, R_base_tcp = _setup(seed=4)
    half_cloud = 0.5 * np.array(tr.BUBBLE_CLOUD_SIZE_MM)
    # (2, 2, 2) mm is the coarsest cubic lattice whose 3x3x6 clouds still cover each cell
    plan = tr.plan_treatment(zone, 2.0, pulses_per_point=10, axes=R_CT, inset_mm=half_cloud)
    run = tr.execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.json")
    T_carm_tcp = np.einsum("ij,njk->nik", invert_transform(T_base_carm), run.reached_T_base_tcp)
    spec = cbct.PhantomSpec()
    # water beyond a segmentation window (8 mm) around the phantom: the noise level is measured there
    truth = cbct.phantom_volume(spec, spacing_mm=1.0, margin_mm=12.0, supersample=2)
    offset = np.array([0.6, -0.4, 1.2])  # bubble cloud off the geometric focal point (§IV)
    clouds = tr.bubble_cloud_mask(truth, T_carm_tcp, offset_mm=offset)
    post = tr.post_treatment_phantom(truth, clouds, cbct.phantom_mask(truth, spec))
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
