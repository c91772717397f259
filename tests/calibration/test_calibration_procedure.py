"""Tests of histostudy.calibration.handeye: Daniilidis AX = XB (§II-C, eq. 5–8) and the robot/C-arm calibration.

References are independent of the code under test: exact synthetic chains (X, Y known, A_i and
B_i built from them), SciPy's quaternions through histostudy.geometry, and OpenCV's
``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_DANIILIDIS)``.
"""

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from histostudy.calibration import handeye as he
from histostudy.geometry import transforms as g


def _truth(rng, n_poses):
    """A random true mounting X = T_flange_transducer, cart Y = T_carm_base, flange poses F_i and
    the exact pose estimates C_i = Y F_i X."""
    X = g.random_transform(rng, 200.0)
    Y = g.random_transform(rng, 800.0)
    F = [g.random_transform(rng, 400.0) for _ in range(n_poses)]
    C = [Y @ Fi @ X for Fi in F]
    return X, Y, F, C


def _cv_eye_in_hand(F, C):
    """OpenCV's Daniilidis for our chain, solving for X = T_flange_transducer: the 'gripper' is the
    flange (gripper2base = T_base_flange), the 'camera' the transducer, the 'target' the C-arm
    (target2cam = T_transducer_carm = inv(T_carm_transducer))."""
    Ci = [np.linalg.inv(c) for c in C]
    R, t = cv2.calibrateHandEye(
        [f[:3, :3] for f in F],
        [f[:3, 3] for f in F],
        [c[:3, :3] for c in Ci],
        [c[:3, 3] for c in Ci],
        method=cv2.CALIB_HAND_EYE_DANIILIDIS,
    )
    return g.make_transform(R, t.ravel())


def _cv_eye_to_hand(F, C):
    """OpenCV for a fixed 'camera' (the C-arm): pass base->gripper (inverted robot poses) and
    target2cam = T_carm_transducer; the result is cam2base = T_base_carm."""
    Fi = [np.linalg.inv(f) for f in F]
    R, t = cv2.calibrateHandEye(
        [f[:3, :3] for f in Fi],
        [f[:3, 3] for f in Fi],
        [c[:3, :3] for c in C],
        [c[:3, 3] for c in C],
        method=cv2.CALIB_HAND_EYE_DANIILIDIS,
    )
    return g.make_transform(R, t.ravel())


def _rot_err_deg(R1, R2):
    return np.degrees(g.rotation_angle(R1.T @ R2))


# ----------------------------------------------------------------------------- derivation of A, B


@pytest.mark.parametrize("seed", range(3))
def test_which_A_and_B_satisfy_AX_eq_XB_for_the_chain(seed):
    """With T_carm_transducer_i = T_carm_base @ T_base_flange_i @ T_flange_transducer exactly,
    A = inv(F_j) F_i and B = inv(C_j) C_i satisfy A X = X B with X = T_flange_transducer, and the
    paper's eq. 7 (inverse reading) holds for eTh = inv(X); the other orders do not."""
    X, Y, F, C = _truth(np.random.default_rng(seed), 2)
    A = np.linalg.inv(F[1]) @ F[0]
    B = np.linalg.inv(C[1]) @ C[0]
    assert np.allclose(A @ X, X @ B, atol=1e-9, rtol=0)
    # eq. 7 with hTc = C, rTe = inv(F), eTh = inv(X) in our point-map notation
    eTh = np.linalg.inv(X)
    assert np.allclose(np.linalg.inv(C[1]) @ C[0] @ eTh, eTh @ np.linalg.inv(F[1]) @ F[0], atol=1e-9, rtol=0)
    # the tempting wrong orders fail (so the check above can fail)
    A_wrong = F[0] @ np.linalg.inv(F[1])
    B_wrong = C[0] @ np.linalg.inv(C[1])
    assert not np.allclose(A_wrong @ X, X @ B_wrong, atol=1e-3)
    assert not np.allclose(A @ np.linalg.inv(X), np.linalg.inv(X) @ B, atol=1e-3)


# ----------------------------------------------------------------------------- dual quaternions


@pytest.mark.parametrize("seed", range(5))
def test_dual_quaternion_conventions(seed):
    rng = np.random.default_rng(seed)
    T1, T2 = g.random_transform(rng, 300.0), g.random_transform(rng, 300.0)
    d1, d2 = he.dual_quaternion_from_transform(T1), he.dual_quaternion_from_transform(T2)
    # real part: geometry's (SciPy's) quaternion, scalar first, w >= 0
    assert np.allclose(d1[:4], g.quaternion_from_matrix(T1[:3, :3]), atol=1e-14)
    # unit dual quaternion: q.q = 1, q.q' = 0, and the dual part carries t: q' = 1/2 t q
    assert np.isclose(d1[:4] @ d1[:4], 1.0) and abs(d1[:4] @ d1[4:]) < 1e-12
    assert np.allclose(he.transform_from_dual_quaternion(d1), T1, atol=1e-12)
    assert np.allclose(he.transform_from_dual_quaternion(-d1), T1, atol=1e-12)
    # products compose like matrices (up to the sign of the representative)
    q = he._qmul(d1[:4], d2[:4])
    qd = he._qmul(d1[:4], d2[4:]) + he._qmul(d1[4:], d2[:4])
    d12 = he.dual_quaternion_from_transform(T1 @ T2)
    s = np.sign(q @ d12[:4])
    assert np.allclose(s * np.concatenate([q, qd]), d12, atol=1e-10)


def test_batched_quaternions_match_scipy_also_near_180_degrees():
    rng = np.random.default_rng(7)
    Rs = [g.random_rotation(rng) for _ in range(50)]
    Rs += [g.rotation_about_axis(rng.normal(size=3), np.pi - eps) for eps in (0.0, 1e-12, 1e-6, 1e-3)]
    Rs += [np.eye(3), g.rotation_about_axis([1, 0, 0], np.pi)]
    q = he._quaternions_from_matrices(np.array(Rs))
    for qi, R in zip(q, Rs):
        ref = g.quaternion_from_matrix(R)
        # at exactly 180 deg w = 0 and either sign is the rotation; compare up to sign
        assert min(np.abs(qi - ref).max(), np.abs(qi + ref).max()) < 1e-12
        assert np.allclose(g.matrix_from_quaternion(qi), R, atol=1e-12)


def test_eq8_matrix_has_the_true_dual_quaternion_in_a_two_dimensional_null_space():
    rng = np.random.default_rng(3)
    X = g.random_transform(rng, 150.0)
    A = [g.random_transform(rng, 300.0) for _ in range(4)]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    dq_a = np.array([he.dual_quaternion_from_transform(a) for a in A])
    dq_b = np.array([he.dual_quaternion_from_transform(b) for b in B])
    dq_b *= np.sign(dq_a[:, :1] * dq_b[:, :1])  # same-sign representatives
    S = he.daniilidis_matrix(dq_a, dq_b)
    assert S.shape == (24, 8)
    dq_x = he.dual_quaternion_from_transform(X)
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
    sol = he.solve_axxb(A, B, return_details=True)
    assert np.abs(sol.X - X).max() < 1e-9
    assert np.abs(he.solve_axxb(A, B) - X).max() < 1e-9
    assert sol.rotation_residuals_deg.max() < 1e-9 and sol.translation_residuals_mm.max() < 1e-9
    assert np.abs(sol.angle_mismatch_deg).max() < 1e-9
    assert sol.singular_values.shape == (8,) and sol.singular_values[-1] < 1e-9 * sol.singular_values[0]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n_poses,pairs", [(3, "all"), (4, "all"), (4, "consecutive"), (10, "all")])
def test_calibrate_recovers_both_unknowns_exactly(seed, n_poses, pairs):
    X, Y, F, C = _truth(np.random.default_rng(seed), n_poses)
    cal = he.calibrate(F, C, pairs=pairs)
    assert np.abs(cal.T_flange_transducer - X).max() < 1e-9
    assert np.abs(cal.T_carm_base - Y).max() < 1e-9
    assert cal.n_poses == n_poses
    assert cal.max_focal_residual_mm < 1e-9 and cal.max_rotation_residual_deg < 1e-9
    n_motions = n_poses * (n_poses - 1) // 2 if pairs == "all" else n_poses - 1
    assert len(cal.motion_rotation_residuals_deg) == n_motions


# ----------------------------------------------------------------------------- OpenCV


@pytest.mark.parametrize("seed", range(6))
def test_matches_opencv_daniilidis_on_noisy_data(seed):
    """Same motions (all pairs, OpenCV's choice), same null space, same root of the quadratic: the
    two implementations agree to rounding even on noisy data, so the tolerance is tight (seen:
    ~1e-15 on rotation entries, ~1e-12 mm on translation; allowed 1e-10 / 1e-8 mm)."""
    rng = np.random.default_rng(100 + seed)
    X, Y, F, C = _truth(rng, 4 + seed)
    C_noisy = [he.perturb_pose(c, 0.5, 0.2, rng) for c in C]
    cal = he.calibrate(F, C_noisy)
    X_cv = _cv_eye_in_hand(F, C_noisy)
    assert np.abs(cal.T_flange_transducer[:3, :3] - X_cv[:3, :3]).max() < 1e-10
    assert np.abs(cal.T_flange_transducer[:3, 3] - X_cv[:3, 3]).max() < 1e-8
    # the noise did move the solution away from the truth (the comparison is not trivial)
    assert np.linalg.norm(cal.T_flange_transducer[:3, 3] - X[:3, 3]) > 1e-3


@pytest.mark.parametrize("seed", range(4))
def test_eye_to_hand_matches_opencv_with_inverted_robot_poses(seed):
    """For the fixed C-arm OpenCV wants base->gripper poses and returns cam2base = T_base_carm;
    solve_axxb with the matching motions (A = F_j inv(F_i), B = C_j inv(C_i)) gives the same."""
    rng = np.random.default_rng(200 + seed)
    X, Y, F, C = _truth(rng, 5)
    C_noisy = [he.perturb_pose(c, 0.5, 0.2, rng) for c in C]
    pairs = he.motion_pairs(5)
    A = [F[j] @ np.linalg.inv(F[i]) for i, j in pairs]
    B = [C_noisy[j] @ np.linalg.inv(C_noisy[i]) for i, j in pairs]
    T_base_carm = he.solve_axxb(A, B)
    T_cv = _cv_eye_to_hand(F, C_noisy)
    assert np.abs(T_base_carm[:3, :3] - T_cv[:3, :3]).max() < 1e-10
    assert np.abs(T_base_carm[:3, 3] - T_cv[:3, 3]).max() < 1e-8
    # exact data: calibrate's T_carm_base (from X and the poses) is OpenCV's inverted
    assert np.abs(he.calibrate(F, C).T_carm_base - np.linalg.inv(_cv_eye_to_hand(F, C))).max() < 1e-9
    # noisy data: a different estimator of the same unknown, equal within the noise (0.5 mm, 0.2 deg)
    cal = he.calibrate(F, C_noisy)
    Y_cv = np.linalg.inv(T_cv)
    assert _rot_err_deg(cal.T_carm_base[:3, :3], Y_cv[:3, :3]) < 1.0
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
    pairs = he.motion_pairs(4)
    A = [np.linalg.inv(Hg[j]) @ Hg[i] for i, j in pairs]
    B = [Hc[j] @ np.linalg.inv(Hc[i]) for i, j in pairs]
    assert np.abs(he.solve_axxb(A, B) - X).max() < 1e-12
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
    dq_a = np.array([he.dual_quaternion_from_transform(a) for a in A])
    dq_b = np.array([he.dual_quaternion_from_transform(np.linalg.inv(X) @ a @ X) for a in A])
    ref = he.solve_axxb_dual_quaternions(dq_a, dq_b)
    flip_a = rng.choice([-1.0, 1.0], size=(5, 1))
    flip_b = rng.choice([-1.0, 1.0], size=(5, 1))
    flip_b[0] = -flip_a[0]  # at least one motion with opposite signs
    X_est = he.solve_axxb_dual_quaternions(dq_a * flip_a, dq_b * flip_b)
    assert np.abs(ref - X).max() < 1e-9 and np.abs(X_est - X).max() < 1e-9


def test_exactly_half_turn_motions_are_recovered_exactly():
    """Rotations of exactly 180 deg: w = 0, so the scalar part says nothing about the sign."""
    rng = np.random.default_rng(11)
    X = g.random_transform(rng, 200.0)
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, -1, 1]]
    A = [g.make_transform(g.rotation_about_axis(ax, np.pi), rng.uniform(-100, 100, 3)) for ax in axes]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    assert np.abs(he.solve_axxb(A, B) - X).max() < 1e-9
    # mixed with ordinary motions too
    A2 = A[:2] + [g.random_transform(rng, 100.0)]
    B2 = [np.linalg.inv(X) @ a @ X for a in A2]
    assert np.abs(he.solve_axxb(A2, B2) - X).max() < 1e-9


def _near_half_turn_poses(seed, n_extra_normal=0):
    """Flange poses linked by ~179.9 deg rotations, pose estimates with 0.05 mm / 0.1 deg noise:
    the noise pushes some camera-side angles past 180 deg, where the non-negative-scalar rule
    picks the opposite sign for B than for A."""
    rng = np.random.default_rng(seed)
    X, Y = g.random_transform(rng, 200.0), g.random_transform(rng, 800.0)
    F = [g.random_transform(rng, 300.0)]
    for _ in range(3):
        F.append(F[-1] @ g.make_transform(g.rotation_about_axis(rng.normal(size=3), np.pi - 2e-3), rng.uniform(-100, 100, 3)))
    C = [he.perturb_pose(Y @ f @ X, 0.05, 0.1, rng) for f in F]
    return X, F, C


def _naive_solution(F, C, pairs):
    """Eq. 8 with the non-negative-scalar sign rule only (what OpenCV does since #24871)."""
    idx = he.motion_pairs(len(F), pairs)
    dq_a = np.array([he.dual_quaternion_from_transform(np.linalg.inv(F[j]) @ F[i]) for i, j in idx])
    dq_b = np.array([he.dual_quaternion_from_transform(np.linalg.inv(C[j]) @ C[i]) for i, j in idx])
    dq, _ = he._solve_null_space(dq_a, dq_b)
    return he.transform_from_dual_quaternion(dq)


@pytest.mark.parametrize("pairs", ["consecutive", "all"])
def test_motions_near_half_turn_keep_consistent_signs(pairs):
    naive_failures = 0
    for seed in (0, 8, 11, 14, 17):
        X, F, C = _near_half_turn_poses(seed)
        cal = he.calibrate(F, C, pairs=pairs)
        assert _rot_err_deg(cal.T_flange_transducer[:3, :3], X[:3, :3]) < 1.0
        assert np.linalg.norm(cal.T_flange_transducer[:3, 3] - X[:3, 3]) < 2.0
        Xn = _naive_solution(F, C, pairs)
        naive_failures += _rot_err_deg(Xn[:3, :3], X[:3, :3]) > 10.0
    # the sign rule alone fails on these data (which is what the test guards against)
    assert naive_failures >= 2


# ----------------------------------------------------------------------------- degenerate / bad input


def test_pure_translations_are_degenerate():
    rng = np.random.default_rng(5)
    F = [g.make_transform(np.eye(3), rng.uniform(-200, 200, 3)) for _ in range(4)]
    X, Y = g.random_transform(rng, 100.0), g.random_transform(rng, 500.0)
    C = [Y @ f @ X for f in F]
    with pytest.raises(he.DegenerateMotionError, match="rotating by"):
        he.calibrate(F, C)


def test_rotations_about_one_axis_are_degenerate():
    rng = np.random.default_rng(6)
    axis = np.array([0.3, -0.5, 0.8])
    F = [g.make_transform(g.rotation_about_axis(axis, a), rng.uniform(-200, 200, 3)) for a in (0.0, 0.4, -0.7, 1.1)]
    X, Y = g.random_transform(rng, 100.0), g.random_transform(rng, 500.0)
    C = [Y @ f @ X for f in F]
    with pytest.raises(he.DegenerateMotionError, match="parallel"):
        he.calibrate(F, C)
    # a single tilt about another axis is enough
    F.append(g.make_transform(g.rotation_about_axis([1, 0, 0], 0.5), [10.0, 0.0, 0.0]))
    C.append(Y @ F[-1] @ X)
    assert np.abs(he.calibrate(F, C).T_flange_transducer - X).max() < 1e-9


def test_too_small_rotations_are_degenerate_and_the_threshold_is_configurable():
    rng = np.random.default_rng(8)
    X = g.random_transform(rng, 100.0)
    A = [g.make_transform(g.rotation_about_axis(ax, np.radians(0.5)), rng.uniform(-50, 50, 3)) for ax in ([1, 0, 0], [0, 1, 0], [0, 0, 1])]
    B = [np.linalg.inv(X) @ a @ X for a in A]
    with pytest.raises(he.DegenerateMotionError, match=r"0\.5"):
        he.solve_axxb(A, B)
    # 0.5 deg motions are exact data here; a lower threshold accepts them
    assert np.abs(he.solve_axxb(A, B, min_rotation_deg=0.1) - X).max() < 1e-6
    with pytest.raises(ValueError, match="min_rotation_deg"):
        he.solve_axxb(A, B, min_rotation_deg=-1.0)


def test_bad_input_errors_name_the_argument():
    X, Y, F, C = _truth(np.random.default_rng(9), 4)
    with pytest.raises(ValueError, match=r"T_base_flange_list must hold at least 3"):
        he.calibrate(F[:2], C[:2])
    with pytest.raises(ValueError, match=r"pair up pose by pose, got 4 and 3"):
        he.calibrate(F, C[:3])
    scaled = C[1].copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(ValueError, match=r"T_carm_transducer_list\[1\]"):
        he.calibrate(F, [C[0], scaled, C[2], C[3]])
    with pytest.raises(ValueError, match=r"T_base_flange_list\[2\] must be a 4x4"):
        he.calibrate([F[0], F[1], F[2][:3], F[3]], C)
    with pytest.raises(TypeError, match="T_base_flange_list must be a list"):
        he.calibrate(F[0], C)
    with pytest.raises(ValueError, match="pairs must be"):
        he.calibrate(F, C, pairs="random")
    with pytest.raises(ValueError, match="A_list and B_list must have the same length"):
        he.solve_axxb(F[:3], C[:2])
    with pytest.raises(ValueError, match=r"dq_a\[0\] must have a unit real part"):
        he.solve_axxb_dual_quaternions(np.ones((2, 8)), np.ones((2, 8)))


# ----------------------------------------------------------------------------- calibration object


def _noisy_calibration(seed=21, n_poses=6, outlier_mm=0.0):
    rng = np.random.default_rng(seed)
    X, Y, F, C = _truth(rng, n_poses)
    C = [he.perturb_pose(c, 0.2, 0.05, rng) for c in C]
    if outlier_mm:
        C[2] = g.make_transform(C[2][:3, :3], C[2][:3, 3] + [outlier_mm, 0.0, 0.0])
    return he.calibrate(F, C), F, C


def test_residuals_are_those_of_the_chain():
    cal, F, C = _noisy_calibration()
    for i, (f, c) in enumerate(zip(F, C)):
        P = cal.T_carm_base @ f @ cal.T_flange_transducer
        assert np.isclose(cal.rotation_residuals_deg[i], _rot_err_deg(P[:3, :3], c[:3, :3]), atol=1e-6)
        assert np.isclose(cal.focal_residuals_mm[i], np.linalg.norm(P[:3, 3] - c[:3, 3]), atol=1e-9)
    assert np.isclose(cal.rms_focal_residual_mm, np.sqrt(np.mean(cal.focal_residuals_mm**2)))
    assert cal.max_rotation_residual_deg == cal.rotation_residuals_deg.max() > 0
    # a focal point off the transducer origin moves the focal residual, not the origin one
    f_mm = [0.0, 0.0, -140.0]
    cal2 = he.calibrate(F, C, focal_point_transducer_mm=f_mm)
    i = 0
    P = cal2.T_carm_base @ F[i] @ cal2.T_flange_transducer
    expected = np.linalg.norm(g.transform_points(P, f_mm) - g.transform_points(C[i], f_mm))
    assert np.isclose(cal2.focal_residuals_mm[i], expected, atol=1e-9)
    # T_carm_base's translation is the least-squares fit of the focal points: mean residual 0
    diffs = [g.transform_points(cal2.T_carm_base @ f @ cal2.T_flange_transducer, f_mm)[0] - g.transform_points(c, f_mm)[0]
             for f, c in zip(F, C)]
    assert np.abs(np.mean(diffs, axis=0)).max() < 1e-9 and np.abs(diffs).max() > 1e-3
    assert np.allclose(cal2.T_flange_transducer, cal.T_flange_transducer)  # X does not depend on f


def test_save_load_round_trip(tmp_path):
    cal, _, _ = _noisy_calibration()
    path = cal.save(tmp_path / "sub" / "handeye.json")
    data = json.loads(path.read_text())
    assert data["schema"] == "histostudy.handeye/1" and data["summary"]["n_poses"] == 6
    back = he.HandEyeCalibration.load(path)
    assert np.array_equal(back.T_flange_transducer, cal.T_flange_transducer)
    assert np.array_equal(back.T_carm_base, cal.T_carm_base)
    assert np.array_equal(back.focal_residuals_mm, cal.focal_residuals_mm)
    assert np.array_equal(back.motion_rotation_residuals_deg, cal.motion_rotation_residuals_deg)
    assert back.summary() == cal.summary()
    assert not list(tmp_path.glob("sub/*.tmp*"))  # atomic: no temporary left behind
    with pytest.raises(ValueError, match="schema"):
        he.HandEyeCalibration.from_dict({**data, "schema": "other"})
    bad = {**data, "T_carm_base": (2 * np.eye(4)).tolist()}
    with pytest.raises(ValueError, match="T_carm_base"):
        he.HandEyeCalibration.from_dict(bad)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        he.HandEyeCalibration.load(tmp_path / "missing.json")


def test_check_refuses_a_calibration_with_an_outlier_pose():
    good, _, _ = _noisy_calibration()
    assert good.check() is good
    bad, _, _ = _noisy_calibration(outlier_mm=15.0)
    assert bad.max_focal_residual_mm > 2.0
    with pytest.raises(he.CalibrationError, match=r"focal-point residual .* mm > 2 mm"):
        bad.check(max_focal_residual_mm=2.0, max_rotation_residual_deg=45.0)
    with pytest.raises(he.CalibrationError, match=r"rotation residual .* deg > 1e-06 deg"):
        good.check(max_focal_residual_mm=100.0, max_rotation_residual_deg=1e-6)
    with pytest.raises(ValueError, match="max_focal_residual_mm"):
        good.check(max_focal_residual_mm=0.0)


@pytest.mark.parametrize("seed", range(3))
def test_flange_pose_for_target_puts_the_focal_point_on_the_target(seed):
    rng = np.random.default_rng(400 + seed)
    X, Y, F, C = _truth(rng, 5)
    focal = np.array([0.0, 0.0, 0.0]) if seed == 0 else rng.uniform(-20, 20, 3)
    cal = he.calibrate(F, C, focal_point_transducer_mm=focal)
    target = rng.uniform(-100, 100, 3)
    # keep the current orientation (a 4x4 pose) or ask for one (3x3)
    for orientation in (C[0], g.random_rotation(rng)):
        F_t = cal.flange_pose_for_target(target, orientation)
        T_true = Y @ F_t @ X  # where the transducer really goes (true chain)
        assert np.abs(g.transform_points(T_true, focal)[0] - target).max() < 1e-9
        R_wanted = np.asarray(orientation)[:3, :3]
        assert np.abs(T_true[:3, :3] - R_wanted).max() < 1e-9
    with pytest.raises(ValueError, match="target_carm_mm"):
        he.flange_pose_for_target(cal, [1.0, 2.0], np.eye(3))
    with pytest.raises(ValueError, match="orientation"):
        he.flange_pose_for_target(cal, target, np.eye(2))
    with pytest.raises(TypeError, match="calibration"):
        he.flange_pose_for_target({"T": 1}, target, np.eye(3))


# ----------------------------------------------------------------------------- sensitivity


def test_calibration_sensitivity_shapes_determinism_and_trends():
    kw = dict(n_poses_list=(4, 12), noise_levels=((0.0, 0.0), (0.5, 0.2)), n_trials=25)
    df = he.calibration_sensitivity(rng=1, **kw)
    assert isinstance(df, pd.DataFrame) and len(df) == 2 * 2 * 25
    for col in ("X_rotation_error_deg", "X_translation_error_mm", "Y_rotation_error_deg",
                "Y_translation_error_mm", "target_error_mm"):
        assert col in df and np.all(np.isfinite(df[col]))
    exact = df[df.noise_translation_mm == 0.0]
    assert exact[["X_translation_error_mm", "Y_translation_error_mm", "target_error_mm"]].to_numpy().max() < 1e-8
    noisy = df[df.noise_translation_mm == 0.5].groupby("n_poses")
    mean_err = noisy["X_translation_error_mm"].mean()
    assert mean_err[4] > 0.1 and mean_err[12] < mean_err[4]  # more poses, smaller error
    assert noisy["target_error_mm"].mean()[12] < noisy["target_error_mm"].mean()[4]
    pd.testing.assert_frame_equal(df, he.calibration_sensitivity(rng=np.random.default_rng(1), **kw))
    with pytest.raises(ValueError, match="n_poses_list"):
        he.calibration_sensitivity(n_poses_list=(2,), rng=0)
    with pytest.raises(TypeError, match="rng"):
        he.calibration_sensitivity(rng=None)
