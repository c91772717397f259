"""Tests of histostudy.calibration.axxb: Daniilidis AX = XB (§II-C, eq. 8), exact recovery, agreement
with OpenCV, the signs of the dual quaternions near half turns, and degenerate motions.

References are independent of the code under test: exact synthetic motions (X known, B_i built
from A_i), and OpenCV's ``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_DANIILIDIS)``.
"""

import cv2
import numpy as np
import pytest
from handeye_chain import chain_truth, opencv_eye_to_hand, rotation_error_deg

from histostudy import calibration as he
from histostudy.calibration.axxb import _solve_null_space, daniilidis_matrix, solve_axxb, solve_axxb_dual_quaternions
from histostudy.calibration.dual_quaternion import dual_quaternion_from_transform, transform_from_dual_quaternion
from histostudy.calibration.procedure import motion_pairs
from histostudy.geometry import transforms as g


def test_eq8_matrix_has_the_true_dual_quaternion_in_a_two_dimensional_null_space():
    rng = np.random.default_rng(3)
    X = g.random_transform(rng, 150.0)
    A = [g.random_transform(rng, 300.0) for _ in range(4)]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    dq_a = np.array([dual_quaternion_from_transform(a) for a in A])
    dq_b = np.array([dual_quaternion_from_transform(b) for b in B])
    dq_b *= np.sign(dq_a[:, :1] * dq_b[:, :1])  # same-sign representatives
    S = daniilidis_matrix(dq_a, dq_b)
    assert S.shape == (24, 8)
    dq_x = dual_quaternion_from_transform(X)
    assert np.abs(S @ dq_x).max() < 1e-10
    # (0, q) is the other null direction; rank exactly 6
    assert np.abs(S @ np.concatenate([np.zeros(4), dq_x[:4]])).max() < 1e-10
    sv = np.linalg.svd(S, compute_uv=False)
    assert sv[5] > 1e-3 * sv[0] and sv[6] < 1e-10 * sv[0]


# ----------------------------------------------------------------------------- exact recovery


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n_motions", [2, 3, 7])
def test_solve_axxb_recovers_X_exactly(seed, n_motions):
    rng = np.random.default_rng(seed)
    X = g.random_transform(rng, 250.0)
    A = [g.random_transform(rng, 300.0) for _ in range(n_motions)]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    sol = solve_axxb(A, B, return_details=True)
    assert np.abs(sol.X - X).max() < 1e-9
    assert np.abs(solve_axxb(A, B) - X).max() < 1e-9
    assert sol.rotation_residuals_deg.max() < 1e-9 and sol.translation_residuals_mm.max() < 1e-9
    assert np.abs(sol.angle_mismatch_deg).max() < 1e-9
    assert sol.singular_values.shape == (8,) and sol.singular_values[-1] < 1e-9 * sol.singular_values[0]


# ----------------------------------------------------------------------------- OpenCV


@pytest.mark.parametrize("seed", range(4))
def test_eye_to_hand_matches_opencv_with_inverted_robot_poses(seed):
    """For the fixed C-arm OpenCV wants base->gripper poses and returns cam2base = T_base_carm;
    solve_axxb with the matching motions (A = F_j inv(F_i), B = C_j inv(C_i)) gives the same."""
    rng = np.random.default_rng(200 + seed)
    X, Y, F, C = chain_truth(rng, 5)
    C_noisy = [he.perturb_pose(c, 0.5, 0.2, rng) for c in C]
    pairs = motion_pairs(5)
    A = [F[j] @ np.linalg.inv(F[i]) for i, j in pairs]
    B = [C_noisy[j] @ np.linalg.inv(C_noisy[i]) for i, j in pairs]
    T_base_carm = solve_axxb(A, B)
    T_cv = opencv_eye_to_hand(F, C_noisy)
    assert np.abs(T_base_carm[:3, :3] - T_cv[:3, :3]).max() < 1e-10
    assert np.abs(T_base_carm[:3, 3] - T_cv[:3, 3]).max() < 1e-8
    # exact data: calibrate's T_carm_base (from X and the poses) is OpenCV's inverted
    assert np.abs(he.calibrate(F, C).T_carm_base - np.linalg.inv(opencv_eye_to_hand(F, C))).max() < 1e-9
    # noisy data: a different estimator of the same unknown, equal within the noise (0.5 mm, 0.2 deg)
    cal = he.calibrate(F, C_noisy)
    Y_cv = np.linalg.inv(T_cv)
    assert rotation_error_deg(cal.T_carm_base[:3, :3], Y_cv[:3, :3]) < 1.0
    assert np.linalg.norm(cal.T_carm_base[:3, 3] - Y_cv[:3, 3]) < 10.0


def _opencv_regression_dataset():
    """Four gripper poses (metres, as OpenCV's test) and the exact X of OpenCV's 4-pose regression
    (test_hand_eye_calibration.cpp): cam2gripper = [[0,0,-1,0.1],[1,0,0,0.2],[0,-1,0,0.3]]."""
    X = np.array([[0.0, 0.0, -1.0, 0.1], [1.0, 0.0, 0.0, 0.2], [0.0, -1.0, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0]])
    T_base_target = g.make_transform(g.matrix_from_euler([0.1, -0.2, 0.3]), [0.8, 0.1, -0.2])
    rotvecs = [[0.0, 0.0, 0.0], [0.4, 0.0, 0.1], [0.0, -0.5, 0.2], [0.3, 0.3, -0.4]]
    positions = [[0.5, 0.0, 0.6], [0.45, 0.1, 0.55], [0.55, -0.1, 0.5], [0.4, 0.05, 0.65]]
    Hg = [g.make_transform(g.matrix_from_rotvec(r), p) for r, p in zip(rotvecs, positions)]  # gripper2base
    Hc = [np.linalg.inv(X) @ np.linalg.inv(h) @ T_base_target for h in Hg]  # target2cam
    return X, Hg, Hc


def test_opencv_four_pose_regression_exact_X():
    X, Hg, Hc = _opencv_regression_dataset()
    # OpenCV's own motions: A = inv(Hg_j) Hg_i, B = Hc_j inv(Hc_i)
    pairs = motion_pairs(4)
    A = [np.linalg.inv(Hg[j]) @ Hg[i] for i, j in pairs]
    B = [Hc[j] @ np.linalg.inv(Hc[i]) for i, j in pairs]
    assert np.abs(solve_axxb(A, B) - X).max() < 1e-12
    # the same through calibrate: flange = gripper, C-arm = target, transducer = camera
    cal = he.calibrate(Hg, [np.linalg.inv(h) for h in Hc])
    assert np.abs(cal.T_flange_transducer - X).max() < 1e-12
    # and OpenCV itself on this dataset
    R, t = cv2.calibrateHandEye(
        [h[:3, :3] for h in Hg], [h[:3, 3] for h in Hg], [h[:3, :3] for h in Hc], [h[:3, 3] for h in Hc],
        method=cv2.CALIB_HAND_EYE_DANIILIDIS,
    )
    assert np.abs(R - X[:3, :3]).max() < 1e-12 and np.abs(t.ravel() - X[:3, 3]).max() < 1e-12


# ----------------------------------------------------------------------------- signs



@pytest.mark.parametrize("seed", range(4))
def test_negated_input_dual_quaternions_give_the_same_X(seed):
    rng = np.random.default_rng(300 + seed)
    X = g.random_transform(rng, 200.0)
    A = [g.random_transform(rng, 300.0) for _ in range(5)]
    dq_a = np.array([dual_quaternion_from_transform(a) for a in A])
    dq_b = np.array([dual_quaternion_from_transform(np.linalg.inv(X) @ a @ X) for a in A])
    ref = solve_axxb_dual_quaternions(dq_a, dq_b)
    flip_a = rng.choice([-1.0, 1.0], size=(5, 1))
    flip_b = rng.choice([-1.0, 1.0], size=(5, 1))
    flip_b[0] = -flip_a[0]  # at least one motion with opposite signs
    X_est = solve_axxb_dual_quaternions(dq_a * flip_a, dq_b * flip_b)
    assert np.abs(ref - X).max() < 1e-9 and np.abs(X_est - X).max() < 1e-9


def test_exactly_half_turn_motions_are_recovered_exactly():
    """Rotations of exactly 180 deg: w = 0, so the scalar part says nothing about the sign."""
    rng = np.random.default_rng(11)
    X = g.random_transform(rng, 200.0)
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, -1, 1]]
    A = [g.make_transform(g.rotation_about_axis(ax, np.pi), rng.uniform(-100, 100, 3)) for ax in axes]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    assert np.abs(solve_axxb(A, B) - X).max() < 1e-9
    # mixed with ordinary motions too
    A2 = A[:2] + [g.random_transform(rng, 100.0)]
    B2 = [np.linalg.inv(X) @ a @ X for a in A2]
    assert np.abs(solve_axxb(A2, B2) - X).max() < 1e-9


def _near_half_turn_poses(seed, n_extra_normal=0):
    """Flange poses linked by ~179.9 deg rotations, pose estimates with 0.05 mm / 0.1 deg noise:
    the noise pushes some camera-side angles past 180 deg, where the non-negative-scalar rule
    picks the opposite sign for B than for A."""
    rng = np.random.default_rng(seed)
    X, Y = g.random_transform(rng, 200.0), g.random_transform(rng, 800.0)
    F = [g.random_transform(rng, 300.0)]
    for _ in range(3):
        R = g.rotation_about_axis(rng.normal(size=3), np.pi - 2e-3)
        F.append(F[-1] @ g.make_transform(R, rng.uniform(-100, 100, 3)))
    C = [he.perturb_pose(Y @ f @ X, 0.05, 0.1, rng) for f in F]
    return X, F, C


def _naive_solution(F, C, pairs):
    """Eq. 8 with the non-negative-scalar sign rule only (what OpenCV does since #24871)."""
    idx = motion_pairs(len(F), pairs)
    dq_a = np.array([dual_quaternion_from_transform(np.linalg.inv(F[j]) @ F[i]) for i, j in idx])
    dq_b = np.array([dual_quaternion_from_transform(np.linalg.inv(C[j]) @ C[i]) for i, j in idx])
    dq, _ = _solve_null_space(dq_a, dq_b)
    return transform_from_dual_quaternion(dq)


@pytest.mark.parametrize("pairs", ["consecutive", "all"])
def test_motions_near_half_turn_keep_consistent_signs(pairs):
    naive_failures = 0
    for seed in (0, 8, 11, 14, 17):
        X, F, C = _near_half_turn_poses(seed)
        cal = he.calibrate(F, C, pairs=pairs)
        assert rotation_error_deg(cal.T_flange_transducer[:3, :3], X[:3, :3]) < 1.0
        assert np.linalg.norm(cal.T_flange_transducer[:3, 3] - X[:3, 3]) < 2.0
        Xn = _naive_solution(F, C, pairs)
        naive_failures += rotation_error_deg(Xn[:3, :3], X[:3, :3]) > 10.0
    # the sign rule alone fails on these data (which is what the test guards against)
    assert naive_failures >= 2


# ----------------------------------------------------------------------------- degenerate / bad input


def test_too_small_rotations_are_degenerate_and_the_threshold_is_configurable():
    rng = np.random.default_rng(8)
    X = g.random_transform(rng, 100.0)
    A = [g.make_transform(g.rotation_about_axis(ax, np.radians(0.5)), rng.uniform(-50, 50, 3))
         for ax in ([1, 0, 0], [0, 1, 0], [0, 0, 1])]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    with pytest.raises(he.DegenerateMotionError, match=r"0\.5"):
        solve_axxb(A, B)
    # 0.5 deg motions are exact data here; a lower threshold accepts them
    assert np.abs(solve_axxb(A, B, min_rotation_deg=0.1) - X).max() < 1e-6
    with pytest.raises(ValueError, match="min_rotation_deg"):
        solve_axxb(A, B, min_rotation_deg=-1.0)
