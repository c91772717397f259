"""Tests of histostudy.study.pose._geometry: the error directions, the margin poses, the rotation error
modulo the half turn, the random poses of the sweeps, the experiments' centre pose."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import default_biplane
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.study.pose.geometry import (
    DIRECTIONS,
    MARGINS,
    axial_symmetric_rotation_error_deg,
    bubble_cloud_centre_mm,
    experiment_pose,
    margin_positions,
    random_pose_in_views,
    rotation_error_modulo_symmetry_deg,
    transducer_axes,
)
from histostudy.transducer import TransducerModel, pose_facing

T_CENTRE = pose_facing((0.1, 1.0, -0.2), focal_point_mm=(3.0, -2.0, 5.0), axial_rotation_rad=0.4)


def test_transducer_axes_are_orthonormal_and_depth_is_propagation():
    axes = transducer_axes(T_CENTRE)
    M = np.stack([axes[d] for d in DIRECTIONS])
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    # Depth points from the transducer (+z side) towards the focal point: along -z.
    np.testing.assert_allclose(axes["depth"], -T_CENTRE[:3, 2], atol=1e-12)


def test_margin_positions_are_r_away_along_each_axis_with_the_same_rotation():
    positions = margin_positions(T_CENTRE, 12.5)
    assert set(positions) == {"centre", "top", "bottom", "left", "right", "front", "back"}
    axes = transducer_axes(T_CENTRE)
    for name, (direction, sign) in MARGINS.items():
        T = positions[name]
        np.testing.assert_allclose(T[:3, :3], T_CENTRE[:3, :3])
        np.testing.assert_allclose(T[:3, 3] - T_CENTRE[:3, 3], sign * 12.5 * axes[direction], atol=1e-12)


def test_axial_symmetric_rotation_error_ignores_the_half_turn_only():
    half_turn = make_transform(np.diag([-1.0, -1.0, 1.0]))
    assert axial_symmetric_rotation_error_deg(T_CENTRE @ half_turn, T_CENTRE) == pytest.approx(0.0, abs=1e-6)
    tilt = make_transform(matrix_from_rotvec([np.deg2rad(3.0), 0.0, 0.0]))
    assert axial_symmetric_rotation_error_deg(T_CENTRE @ tilt, T_CENTRE) == pytest.approx(3.0)
    quarter = make_transform(matrix_from_rotvec([0.0, 0.0, np.pi / 2]))
    assert axial_symmetric_rotation_error_deg(T_CENTRE @ quarter, T_CENTRE) == pytest.approx(90.0)


def test_rotation_error_modulo_symmetry_takes_the_half_turn_only_where_the_model_allows_it():
    half_turn = make_transform(np.diag([-1.0, -1.0, 1.0]))
    tilt = make_transform(matrix_from_rotvec([np.deg2rad(4.0), 0.0, 0.0]))
    estimate = T_CENTRE @ half_turn @ tilt
    assert rotation_error_modulo_symmetry_deg(estimate, T_CENTRE, half_turn=True) == (pytest.approx(4.0), True)
    assert rotation_error_modulo_symmetry_deg(estimate, T_CENTRE, half_turn=False) == (pytest.approx(180.0, abs=4.1),
                                                                                       True)
    assert rotation_error_modulo_symmetry_deg(T_CENTRE @ tilt, T_CENTRE, half_turn=True) == (pytest.approx(4.0), False)


def test_random_poses_keep_the_given_points_in_every_view():
    views = default_biplane()
    rng = np.random.default_rng(0)
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 120.0]])
    for _ in range(10):
        T = random_pose_in_views(rng, views, visible_points_mm=points)
        world = points @ T[:3, :3].T + T[:3, 3]
        assert np.all(np.abs(T[:3, 3]) <= 100.0)
        for v in views:
            assert np.all(v.in_image(v.project(world)))
    with pytest.raises(RuntimeError, match="no pose"):
        random_pose_in_views(rng, views, visible_points_mm=[[0.0, 0.0, 5000.0]], max_tries=20)


def test_bubble_cloud_centre_is_the_physical_focal_point_plus_the_offset_in_the_pose():
    physical = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))
    offset = np.array([0.5, -1.0, 2.0])
    expected = T_CENTRE[:3, :3] @ (physical.focal_point_mm + offset) + T_CENTRE[:3, 3]
    np.testing.assert_allclose(bubble_cloud_centre_mm(physical, T_CENTRE, offset), expected, atol=1e-12)
    # No offset: the acoustic focal point; the transducer axis points along -depth.
    zero = bubble_cloud_centre_mm(physical, T_CENTRE, (0.0, 0.0, 0.0))
    moved = bubble_cloud_centre_mm(physical, T_CENTRE, (0.0, 0.0, 2.0))
    np.testing.assert_allclose(moved - zero, -2.0 * transducer_axes(T_CENTRE)["depth"], atol=1e-12)


def test_experiment_pose_keeps_the_focal_point_within_the_jitter_and_the_axis_near_vertical():
    config = PoseStudyConfig(tilt_sd_deg=0.0, focal_jitter_mm=5.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        T = experiment_pose(rng, config, (10.0, -20.0, 30.0))
        assert np.all(np.abs(T[:3, 3] - [10.0, -20.0, 30.0]) <= 5.0)
        # No tilt: the transducer looks along world +y (downwards in the C-arm frame), its z axis up.
        np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)
    same = experiment_pose(np.random.default_rng(1), config, (0.0, 0.0, 0.0))
    np.testing.assert_array_equal(same, experiment_pose(np.random.default_rng(1), config, (0.0, 0.0, 0.0)))
