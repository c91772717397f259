"""UR5e kinematics (histostudy.robot.kinematics) against the independent reference ur-analytic-ik."""

import math

import numpy as np
import pytest
import ur_analytic_ik

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.robot import UnreachablePoseError
from histostudy.robot import kinematics as k

SEEDS = range(5)


def _random_q(rng, n):
    return rng.uniform(-math.pi, math.pi, size=(n, 6))


@pytest.mark.parametrize("seed", SEEDS)
def test_forward_kinematics_matches_reference(seed):
    for q in _random_q(np.random.default_rng(seed), 20):
        T = k.forward_kinematics(q)
        T_ref = np.asarray(ur_analytic_ik.ur5e.forward_kinematics(*q))  # metres
        assert np.allclose(T[:3, :3], T_ref[:3, :3], atol=1e-12)
        assert np.allclose(T[:3, 3], 1000.0 * T_ref[:3, 3], atol=1e-9)


def test_forward_kinematics_of_zero_is_the_dh_table():
    # At q = 0 the arm is stretched along -x: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    T = k.forward_kinematics(np.zeros(6))
    assert np.allclose(T[:3, 3], [-425.0 - 392.2, -(133.3 + 99.6), 162.5 - 99.7], atol=1e-9)


def _same_angles(a, b, tol):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))).max() < tol


@pytest.mark.parametrize("seed", SEEDS)
def test_inverse_kinematics_finds_every_reference_solution(seed):
    for q in _random_q(np.random.default_rng(100 + seed), 20):
        T = k.forward_kinematics(q)
        ours = k.inverse_kinematics(T)
        T_ref = np.ascontiguousarray(np.asarray(ur_analytic_ik.ur5e.forward_kinematics(*q)))
        ref = ur_analytic_ik.ur5e.inverse_kinematics(T_ref)
        assert len(ours) == len(ref) >= 1
        for r in ref:
            assert any(_same_angles(o, r, 1e-7) for o in ours)
        for o in ours:  # and every solution of ours reaches the pose
            T_o = k.forward_kinematics(o)
            assert np.abs(T_o[:3, 3] - T[:3, 3]).max() < 1e-6
            assert np.abs(T_o[:3, :3] - T[:3, :3]).max() < 1e-9
        assert any(_same_angles(o, q, 1e-7) for o in ours)


@pytest.mark.parametrize("seed", SEEDS)
def test_closest_solution_returns_the_configuration_it_started_from(seed):
    # Within +-2 pi (not only +-pi): the unwrapping must pick the same turn as the reference joints.
    rng = np.random.default_rng(200 + seed)
    for q in rng.uniform(-2 * math.pi + 0.01, 2 * math.pi - 0.01, size=(20, 6)):
        q_near = q + rng.normal(0, 0.02, 6)
        q_near = np.clip(q_near, -2 * math.pi, 2 * math.pi)
        got = k.inverse_kinematics_closest(k.forward_kinematics(q), q_near)
        assert np.allclose(got, q, atol=1e-7)
        assert np.all(np.abs(got) <= k.JOINT_LIMIT_RAD)


def test_closest_solution_agrees_with_reference_closest():
    rng = np.random.default_rng(7)
    for q in _random_q(rng, 20):
        q_near = _random_q(rng, 1)[0]
        T = k.forward_kinematics(q)
        ours = k.inverse_kinematics_closest(T, q_near)
        T_m = T.copy()
        T_m[:3, 3] /= 1000.0
        ref = np.asarray(ur_analytic_ik.ur5e.inverse_kinematics_closest(np.ascontiguousarray(T_m), *q_near))
        ref = np.atleast_2d(ref)[0]
        # The reference measures distance its own way; ours must be at least as close in joint
        # travel to every reference solution taken by its nearest turn (all lie within +-2 pi here).
        ref_travel = np.linalg.norm(np.angle(np.exp(1j * (ref - q_near))))
        assert np.linalg.norm(ours - q_near) <= ref_travel + 1e-9
        all_ref = ur_analytic_ik.ur5e.inverse_kinematics(np.ascontiguousarray(T_m))
        best_ref = min(np.linalg.norm(np.angle(np.exp(1j * (np.asarray(r) - q_near)))) for r in all_ref)
        assert np.isclose(np.linalg.norm(ours - q_near), best_ref, atol=1e-7)


def test_wrist_singularity_reaches_the_pose():
    q = np.array([0.3, -1.2, 1.1, -0.5, 0.0, 0.7])  # theta5 = 0: axes 4 and 6 aligned
    T = k.forward_kinematics(q)
    sols = k.inverse_kinematics(T, theta6_free=0.7)
    assert len(sols) >= 1
    for s in sols:
        assert np.allclose(k.forward_kinematics(s), T, atol=1e-6)


def test_out_of_reach_pose_has_no_solution():
    T = make_transform(matrix_from_rotvec([math.pi, 0, 0]), [900.0, 300.0, 400.0])
    assert len(k.inverse_kinematics(T)) == 0
    with pytest.raises(UnreachablePoseError, match="no inverse-kinematics solution"):
        k.inverse_kinematics_closest(T, np.zeros(6))


def test_bad_joint_input_names_the_argument():
    with pytest.raises(ValueError, match="q_rad"):
        k.forward_kinematics([0, 0, np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="q_near_rad"):
        k.inverse_kinematics_closest(np.eye(4), [0, 0, 7.0, 0, 0, 0])
    with pytest.raises(ValueError, match="T_base_flange"):
        k.inverse_kinematics(np.full((4, 4), np.nan))


def test_joint_frames_are_the_link_chain_of_the_forward_kinematics():
    q = _random_q(np.random.default_rng(4), 1)[0]
    frames = k.joint_frames(q)
    assert frames.shape == (7, 4, 4)
    assert np.array_equal(frames[0], np.eye(4))
    assert np.allclose(frames[-1], k.forward_kinematics(q), atol=1e-9)
    # Consecutive origins are the DH link lengths apart (sqrt(d^2 + a^2)) in any configuration.
    gaps = np.linalg.norm(np.diff(frames[:, :3, 3], axis=0), axis=1)
    assert np.allclose(gaps, np.hypot(k.UR5E.d_mm, k.UR5E.a_mm), atol=1e-9)
    assert np.allclose(k.joint_frames(np.zeros(6))[1, :3, 3], [0.0, 0.0, 162.5])
    with pytest.raises(ValueError, match="q_rad"):
        k.joint_frames([0.0] * 5)


def test_linear_path_stays_on_the_line_and_is_continuous():
    q0 = np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
    T_flange_tcp = make_transform(t_mm=[0.0, 0.0, 150.0])
    T0 = k.forward_kinematics(q0) @ T_flange_tcp
    T1 = make_transform(T0[:3, :3] @ matrix_from_rotvec([0.0, 0.3, 0.0]), T0[:3, 3] + [120.0, 80.0, -60.0])
    fractions, path = k.linear_path_joints(T0, T1, T_flange_tcp, q0)
    assert fractions[0] == 0.0 and fractions[-1] == 1.0 and len(path) == len(fractions)
    assert np.allclose(k.forward_kinematics(path[-1]) @ T_flange_tcp, T1, atol=1e-6)
    for s, q in zip(fractions, path):
        T = k.forward_kinematics(q) @ T_flange_tcp
        assert np.allclose(T, k.interpolate_pose(T0, T1, s), atol=1e-6)
    assert np.abs(np.diff(path, axis=0)).max() < 0.5


def test_linear_path_through_the_base_axis_is_unreachable():
    q0 = np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
    T0 = k.forward_kinematics(q0)
    T1 = T0.copy()
    T1[:2, 3] = -T0[:2, 3]  # point-mirror about the base axis: the straight line crosses it
    with pytest.raises(UnreachablePoseError, match="straight path"):
        k.linear_path_joints(T0, T1, np.eye(4), q0)
