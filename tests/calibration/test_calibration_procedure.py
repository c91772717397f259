"""Tests of histostudy.calibration.procedure: the robot/C-arm calibration (§II-C, eq. 5-7), which A and
B the chain gives, exact recovery of both unknowns, OpenCV on noisy data, the residuals, the
persistence, the residual gate, and the flange pose for a target.

References are independent of the code under test: exact synthetic chains (X, Y known, C_i built
from them), SciPy's quaternions through histostudy.geometry, and OpenCV's
``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_DANIILIDIS)``.
"""

import json

import numpy as np
import pytest
from handeye_chain import chain_truth, opencv_eye_in_hand, rotation_error_deg

from histostudy import calibration as he
from histostudy.calibration.axxb import solve_axxb, solve_axxb_dual_quaternions
from histostudy.calibration.procedure import flange_pose_for_target
from histostudy.geometry import transforms as g

# ----------------------------------------------------------------------------- derivation of A, B


@pytest.mark.parametrize("seed", range(3))
def test_which_A_and_B_satisfy_AX_eq_XB_for_the_chain(seed):
    """With T_carm_transducer_i = T_carm_base @ T_base_flange_i @ T_flange_transducer exactly,
    A = inv(F_j) F_i and B = inv(C_j) C_i satisfy A X = X B with X = T_flange_transducer, and the
    paper's eq. 7 (inverse reading) holds for eTh = inv(X); the other orders do not."""
    X, Y, F, C = chain_truth(np.random.default_rng(seed), 2)
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



@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n_poses,pairs", [(3, "all"), (4, "all"), (4, "consecutive"), (10, "all")])
def test_calibrate_recovers_both_unknowns_exactly(seed, n_poses, pairs):
    X, Y, F, C = chain_truth(np.random.default_rng(seed), n_poses)
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
    X, Y, F, C = chain_truth(rng, 4 + seed)
    C_noisy = [he.perturb_pose(c, 0.5, 0.2, rng) for c in C]
    cal = he.calibrate(F, C_noisy)
    X_cv = opencv_eye_in_hand(F, C_noisy)
    assert np.abs(cal.T_flange_transducer[:3, :3] - X_cv[:3, :3]).max() < 1e-10
    assert np.abs(cal.T_flange_transducer[:3, 3] - X_cv[:3, 3]).max() < 1e-8
    # the noise did move the solution away from the truth (the comparison is not trivial)
    assert np.linalg.norm(cal.T_flange_transducer[:3, 3] - X[:3, 3]) > 1e-3


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



def test_bad_input_errors_name_the_argument():
    X, Y, F, C = chain_truth(np.random.default_rng(9), 4)
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
        solve_axxb(F[:3], C[:2])
    with pytest.raises(ValueError, match=r"dq_a\[0\] must have a unit real part"):
        solve_axxb_dual_quaternions(np.ones((2, 8)), np.ones((2, 8)))


# ----------------------------------------------------------------------------- calibration object


def _noisy_calibration(seed=21, n_poses=6, outlier_mm=0.0):
    rng = np.random.default_rng(seed)
    X, Y, F, C = chain_truth(rng, n_poses)
    C = [he.perturb_pose(c, 0.2, 0.05, rng) for c in C]
    if outlier_mm:
        C[2] = g.make_transform(C[2][:3, :3], C[2][:3, 3] + [outlier_mm, 0.0, 0.0])
    return he.calibrate(F, C), F, C


def test_residuals_are_those_of_the_chain():
    cal, F, C = _noisy_calibration()
    for i, (f, c) in enumerate(zip(F, C)):
        P = cal.T_carm_base @ f @ cal.T_flange_transducer
        assert np.isclose(cal.rotation_residuals_deg[i], rotation_error_deg(P[:3, :3], c[:3, :3]), atol=1e-6)
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
    diffs = [g.transform_points(cal2.T_carm_base @ f @ cal2.T_flange_transducer, f_mm)[0]
             - g.transform_points(c, f_mm)[0] for f, c in zip(F, C)]
    assert np.abs(np.mean(diffs, axis=0)).max() < 1e-9 and np.abs(diffs).max() > 1e-3
    assert np.allclose(cal2.T_flange_transducer, cal.T_flange_transducer)  # X does not depend on f


def test_save_load_round_trip(tmp_path):
    cal, _, _ = _noisy_calibration()
    path = cal.save(tmp_path / "sub" / "handeye.json")
    data = json.loads(path.read_text())
    assert data["schema"] == "histostudy.calibration/1" and data["summary"]["n_poses"] == 6
    back = he.HandEyeCalibration.load(path)
    assert np.array_equal(back.T_flange_transducer, cal.T_flange_transducer)
    assert np.array_equal(back.T_carm_base, cal.T_carm_base)
    assert np.array_equal(back.focal_residuals_mm, cal.focal_residuals_mm)
    assert np.array_equal(back.motion_rotation_residuals_deg, cal.motion_rotation_residuals_deg)
    assert back.summary() == cal.summary()
    assert not list(tmp_path.glob("sub/*.tmp*"))  # atomic: no temporary left behind
    with pytest.raises(ValueError, match="schema"):
        he.HandEyeCalibration.from_dict({**data, "schema": "other"})
    # a file written by 0.1.0, whose tag named the old module, loads to the same calibration
    legacy = he.HandEyeCalibration.from_dict({**data, "schema": "histostudy.handeye/1"})
    assert np.array_equal(legacy.T_carm_base, cal.T_carm_base) and legacy.summary() == cal.summary()
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
    X, Y, F, C = chain_truth(rng, 5)
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
        flange_pose_for_target(cal, [1.0, 2.0], np.eye(3))
    with pytest.raises(ValueError, match="orientation"):
        flange_pose_for_target(cal, target, np.eye(2))
    with pytest.raises(TypeError, match="calibration"):
        flange_pose_for_target({"T": 1}, target, np.eye(3))
