"""Tests of histostudy.pose.init (§II-B.4): each initialisation stage on its own, on noise-free
reference labels of a known pose."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_angle
from histostudy.imaging import default_biplane, render_labels
from histostudy.learning import angles_from_direction, beam_direction_of_pose, direction_candidates, select_direction
from histostudy.pose import DistanceMaps, PoseCost
from histostudy.pose.init import (
    COARSE_GRID,
    FINE_GRID,
    GridSpec,
    axial_minima,
    axial_search,
    grid_offsets,
    grid_search,
    initialise_pose,
    rotation_from_direction,
)
from histostudy.transducer import TransducerModel, pose_facing

T_TRUE = pose_facing((0.2, 1.0, -0.3), focal_point_mm=(22.0, -14.0, 9.0), axial_rotation_rad=0.6)


@pytest.fixture(scope="module")
def setup():
    views = default_biplane()
    model = TransducerModel.build(spacing_mm=0.47)
    fine = TransducerModel.build(spacing_mm=0.25)
    maps = [DistanceMaps(v, render_labels(fine, T_TRUE, v), occlusion_aware=True) for v in views]
    paper = PoseCost(model.points, maps).subset(1500, np.random.default_rng(0))
    # The robust initialisation's scoring: distances truncated at 30 px, off-detector points too.
    cost = PoseCost(paper.points, [m.truncated(30.0) for m in maps], outside_distance_px=30.0)
    return {"views": views, "cost": cost, "paper": paper,
            "view_costs": [cost.select_views(i) for i in range(len(views))]}


def in_plane_distance(view, a, b):
    """Distance between two points measured in the view's detector-parallel plane (mm)."""
    d = np.asarray(a) - np.asarray(b)
    beam = view.detector_axes[2]
    return float(np.linalg.norm(d - (d @ beam) * beam))


def test_rotation_from_direction_points_the_transducer_axis_and_turns_about_it():
    direction = np.array([0.3, -1.0, 0.2])
    for angle in (0.0, 0.7, 2.0):
        R = rotation_from_direction(direction, angle)
        np.testing.assert_allclose(-R[:, 2], direction / np.linalg.norm(direction), atol=1e-12)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    # Two axial angles differ by a rotation of exactly their difference about the axis.
    R0, R1 = rotation_from_direction(direction, 0.2), rotation_from_direction(direction, 0.9)
    assert np.rad2deg(rotation_angle(R0.T @ R1)) == pytest.approx(np.rad2deg(0.7), abs=1e-9)
    np.testing.assert_allclose(rotation_from_direction(beam_direction_of_pose(T_TRUE), 0.6), T_TRUE[:3, :3], atol=1e-12)


def test_grids_are_the_papers_and_lie_in_the_detector_plane():
    assert COARSE_GRID.n_u * COARSE_GRID.n_v == 130 and COARSE_GRID.step_mm == 30.0
    assert FINE_GRID.n_u * FINE_GRID.n_v == 49 and FINE_GRID.step_mm == 5.0
    view = default_biplane()[0]
    offsets = grid_offsets(view, COARSE_GRID)
    assert offsets.shape == (130, 3)
    np.testing.assert_allclose(offsets @ view.detector_axes[2], 0.0, atol=1e-9)
    np.testing.assert_allclose(offsets.mean(axis=0), 0.0, atol=1e-9)
    # Extent: 12 x 9 steps of 3 cm (about the paper's 40 x 30 cm).
    uv = offsets @ view.detector_axes[:2].T
    assert np.ptp(uv[:, 0]) == pytest.approx(360.0) and np.ptp(uv[:, 1]) == pytest.approx(270.0)
    with pytest.raises(ValueError, match="GridSpec"):
        GridSpec(0, 3, 5.0)


def test_candidate_selection_picks_the_right_mirror_in_both_views():
    views = default_biplane()
    rng = np.random.default_rng(3)
    for _ in range(20):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        cands = [direction_candidates(*angles_from_direction(d, v), v) for v in views]
        chosen, idx, spread = select_direction(cands)
        np.testing.assert_allclose(chosen, d, atol=1e-9)
        # The right mirror in each view is the one pointing the way d does relative to that detector.
        for v, i in zip(views, idx):
            assert i == (0 if d @ v.detector_axes[2] <= 0 else 1)
        assert spread < 1e-9


def test_grid_search_lands_within_a_grid_step(setup):
    view_a, view_b = setup["views"]
    R = T_TRUE[:3, :3]
    truth = T_TRUE[:3, 3]
    point, c, n = grid_search(setup["view_costs"][0], R, np.zeros(3), view_a, COARSE_GRID)
    assert n == 130
    assert in_plane_distance(view_a, point, truth) <= COARSE_GRID.step_mm * np.sqrt(0.5) + 1e-9
    # Plane B's coarse grid, centred on plane A's best point, then the fine grids.
    point, _, _ = grid_search(setup["view_costs"][1], R, point, view_b, COARSE_GRID)
    assert in_plane_distance(view_b, point, truth) <= COARSE_GRID.step_mm * np.sqrt(0.5) + 1e-9
    for i, view in enumerate((view_a, view_b)):
        point, _, n = grid_search(setup["view_costs"][i], R, point, view, FINE_GRID)
        assert n == 49
        assert in_plane_distance(view, point, truth) <= FINE_GRID.step_mm * np.sqrt(0.5) + 1e-9


def test_the_papers_outside_constant_makes_an_off_detector_pose_cheapest(setup):
    """Why the default initialisation truncates: with 0.1 px for points off the map, a grid point
    with much of the model off plane A's detector beats the grid point nearest the truth (a few
    mm off, so every visible point is tens of pixels from its feature)."""
    view_a = setup["views"][0]
    paper_a = setup["paper"].select_views(0)
    R, truth = T_TRUE[:3, :3], T_TRUE[:3, 3]
    point, best, _ = grid_search(paper_a, R, np.zeros(3), view_a, COARSE_GRID)
    assert in_plane_distance(view_a, point, truth) > 3 * COARSE_GRID.step_mm
    grid = grid_offsets(view_a, COARSE_GRID)
    nearest = grid[np.argmin([in_plane_distance(view_a, g, truth) for g in grid])]
    assert best < paper_a(make_transform(R, nearest))
    # The robust scoring picks the grid point nearest the truth instead.
    robust_point, _, _ = grid_search(setup["view_costs"][0], R, np.zeros(3), view_a, COARSE_GRID)
    np.testing.assert_allclose(robust_point, nearest, atol=1e-9)


def test_axial_search_finds_the_axial_angle_modulo_the_half_turn(setup):
    direction = beam_direction_of_pose(T_TRUE)
    R, angle, c, n = axial_search(setup["cost"], direction, T_TRUE[:3, 3])
    assert n == 72 and 0 <= angle < np.pi
    step = np.pi / 72
    diff = abs((angle - 0.6 + np.pi / 2) % np.pi - np.pi / 2)
    assert diff <= step / 2 + 1e-9, np.rad2deg(diff)
    assert c == pytest.approx(setup["cost"](make_transform(R, T_TRUE[:3, 3])))
    minima, n = axial_minima(setup["cost"], direction, T_TRUE[:3, 3], count=3)
    assert minima[0][0] == pytest.approx(angle) and [m[1] for m in minima] == sorted(m[1] for m in minima)


def test_initialise_pose_from_the_true_direction_is_within_a_fine_step(setup):
    direction = beam_direction_of_pose(T_TRUE)
    for options in (dict(), dict(axial_seeds_deg=(0.0, 45.0, 90.0, 135.0), fine_after_axial=True, n_hypotheses=3)):
        res = initialise_pose(direction, setup["views"], setup["view_costs"], setup["cost"], **options)
        assert np.linalg.norm(res.T_carm_transducer[:3, 3] - T_TRUE[:3, 3]) < FINE_GRID.step_mm
        axis_err = np.rad2deg(np.arccos(np.clip(-res.T_carm_transducer[:3, 2] @ direction, -1, 1)))
        assert axis_err < 1e-6
        # The axial angle is right up to the transducer's half-turn symmetry.
        R_rel = res.T_carm_transducer[:3, :3].T @ T_TRUE[:3, :3]
        assert min(np.rad2deg(rotation_angle(R_rel)), 180 - np.rad2deg(rotation_angle(R_rel))) < 5.0
        assert res.n_evaluations >= 2 * 130 + 2 * 49 + 72
        assert res.cost == pytest.approx(setup["cost"](res.T_carm_transducer))


def test_initialise_pose_rejects_mismatched_inputs(setup):
    direction = beam_direction_of_pose(T_TRUE)
    with pytest.raises(ValueError, match="equal length"):
        initialise_pose(direction, setup["views"], setup["view_costs"][:1], setup["cost"])
    with pytest.raises(ValueError, match="axial_seeds_deg"):
        initialise_pose(direction, setup["views"], setup["view_costs"], setup["cost"], axial_seeds_deg=())
    with pytest.raises(ValueError, match="n_angles"):
        axial_search(setup["cost"], direction, T_TRUE[:3, 3], n_angles=0)


def test_a_seeded_chain_competes_with_the_coarse_grid(setup):
    direction = beam_direction_of_pose(T_TRUE)
    # A one-point coarse grid 20 cm away stands for a coarse grid whose optimum lies in the wrong region.
    far = dict(centre_mm=T_TRUE[:3, 3] + 200.0 * setup["views"][0].detector_axes[0], coarse=GridSpec(1, 1, 30.0),
               medium=GridSpec(7, 7, 10.0), axial_seeds_deg=(0.0,), fine_after_axial=True, n_hypotheses=2)
    lost = initialise_pose(direction, setup["views"], setup["view_costs"], setup["cost"], **far)
    assert np.linalg.norm(lost.T_carm_transducer[:3, 3] - T_TRUE[:3, 3]) > 50.0
    seed_mm = T_TRUE[:3, 3] + np.array([8.0, -6.0, 5.0])
    found = initialise_pose(direction, setup["views"], setup["view_costs"], setup["cost"],
                            seeded=lambda d: [(np.rad2deg(0.6) + 10.0, seed_mm)], **far)
    assert np.linalg.norm(found.T_carm_transducer[:3, 3] - T_TRUE[:3, 3]) < FINE_GRID.step_mm
    assert found.stages["seeded_0"]["point_mm"] == pytest.approx(seed_mm)
    assert found.cost < lost.cost
