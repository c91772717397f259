"""Property tests of histostudy.geometry: round trips, orthonormality, conventions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from histostudy.geometry import transforms as g

SEEDS = range(20)


@pytest.mark.parametrize("seed", SEEDS)
def test_random_rotation_is_proper_orthonormal(seed):
    R = g.random_rotation(np.random.default_rng(seed))
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)


@pytest.mark.parametrize("seed", SEEDS)
def test_rotvec_quaternion_euler_round_trips(seed):
    rng = np.random.default_rng(seed)
    R = g.random_rotation(rng)
    assert np.allclose(g.matrix_from_rotvec(g.rotvec_from_matrix(R)), R, atol=1e-12)
    q = g.quaternion_from_matrix(R)
    assert q[0] >= 0 and np.isclose(np.linalg.norm(q), 1.0)
    assert np.allclose(g.matrix_from_quaternion(q), R, atol=1e-12)
    assert np.allclose(g.matrix_from_quaternion(-q), R, atol=1e-12)  # q and -q: one rotation
    for conv in ("xyz", "ZYX", "zxz"):
        assert np.allclose(g.matrix_from_euler(g.euler_from_matrix(R, conv), conv), R, atol=1e-10)


def test_quaternion_is_scalar_first():
    # 90 deg about z: q = [cos 45, 0, 0, sin 45]
    q = g.quaternion_from_matrix(g.rotation_about_axis([0, 0, 1], np.pi / 2))
    assert np.allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)])


def test_extrinsic_xyz_means_fixed_axes_x_then_y_then_z():
    a, b, c = 0.3, -0.7, 1.1
    expected = (g.rotation_about_axis([0, 0, 1], c) @ g.rotation_about_axis([0, 1, 0], b)
                @ g.rotation_about_axis([1, 0, 0], a))
    assert np.allclose(g.matrix_from_euler([a, b, c], "xyz"), expected)
    # intrinsic XYZ: about the moving x, then y', then z''
    expected_intr = (g.rotation_about_axis([1, 0, 0], a) @ g.rotation_about_axis([0, 1, 0], b)
                     @ g.rotation_about_axis([0, 0, 1], c))
    assert np.allclose(g.matrix_from_euler([a, b, c], "XYZ"), expected_intr)


def test_rotation_about_axis_is_right_handed():
    R = g.rotation_about_axis([0, 0, 2.0], np.pi / 2)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])


@pytest.mark.parametrize("seed", SEEDS)
def test_transform_inverse_and_composition(seed):
    rng = np.random.default_rng(seed)
    T_a_b, T_b_c = g.random_transform(rng, 200.0), g.random_transform(rng, 200.0)
    assert np.allclose(g.compose(T_a_b, g.invert_transform(T_a_b)), np.eye(4), atol=1e-12)
    pts = rng.normal(size=(10, 3)) * 50
    T_a_c = g.compose(T_a_b, T_b_c)
    assert np.allclose(g.transform_points(T_a_c, pts), g.transform_points(T_a_b, g.transform_points(T_b_c, pts)))
    # distances are preserved by a rigid transform
    moved = g.transform_points(T_a_b, pts)
    assert np.allclose(np.linalg.norm(moved[1:] - moved[0], axis=1), np.linalg.norm(pts[1:] - pts[0], axis=1))


@pytest.mark.parametrize("seed", SEEDS)
def test_pose_params_round_trip(seed):
    T = g.random_transform(np.random.default_rng(seed), 100.0)
    assert np.allclose(g.transform_from_params(g.params_from_transform(T)), T, atol=1e-12)


def test_rotation_angle_matches_scipy():
    rng = np.random.default_rng(3)
    for _ in range(10):
        R = g.random_rotation(rng)
        assert np.isclose(g.rotation_angle(R), Rotation.from_matrix(R).magnitude())


def test_random_draws_are_seeded():
    a = g.random_transform(np.random.default_rng(7), 50)
    b = g.random_transform(np.random.default_rng(7), 50)
    c = g.random_transform(np.random.default_rng(8), 50)
    assert np.array_equal(a, b) and not np.allclose(a, c)
    with pytest.raises(TypeError, match="rng"):
        g.random_rotation(7)


@pytest.mark.parametrize(
    "T, match",
    [
        (np.eye(3), "4x4"),
        (np.diag([1.0, 1.0, 1.0, 2.0]), "bottom row"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "proper rotation"),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), "proper rotation"),
        (np.full((4, 4), np.nan), "finite"),
    ],
)
def test_non_rigid_transforms_are_rejected_by_name(T, match):
    with pytest.raises(ValueError, match=match) as err:
        g.check_rigid(T, "T_carm_transducer")
    assert "T_carm_transducer" in str(err.value)
    with pytest.raises(ValueError):
        g.invert_transform(T)


def test_bad_inputs_name_the_argument():
    with pytest.raises(ValueError, match="convention"):
        g.matrix_from_euler([0, 0, 0], "xYz")
    with pytest.raises(ValueError, match="axis"):
        g.rotation_about_axis([0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="params"):
        g.transform_from_params([0, 0, 0, 1, 2])
    with pytest.raises(ValueError, match="points_mm"):
        g.as_points(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="quaternion"):
        g.matrix_from_quaternion([0, 0, 0, 0])


def test_fit_sphere_recovers_a_noisy_cap():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d[:, 2] = np.abs(d[:, 2]) + 1.0  # a cap, not a whole sphere
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.array([3.0, -2.0, 10.0])
    pts = centre + 138.7 * d + rng.normal(scale=0.05, size=d.shape)
    c, r = g.fit_sphere(pts)
    assert np.allclose(c, centre, atol=0.05) and r == pytest.approx(138.7, abs=0.05)
    with pytest.raises(ValueError, match="at least 4"):
        g.fit_sphere(pts[:3])
