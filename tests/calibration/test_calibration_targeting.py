"""histostudy.calibration.targeting: the chain run to a target, and the half-turn reading of pose
estimates, on an exact synthetic chain (tests/calibration/handeye_chain.py)."""

import numpy as np
import pytest
from handeye_chain import chain_truth

from histostudy.calibration import (
    DOWN,
    HALF_TURN,
    DegenerateMotionError,
    calibrate,
    calibrate_half_turns,
    target_orientation,
    tcp_for_target,
)
from histostudy.geometry import transforms as g


def test_half_turned_estimates_give_the_calibration_of_the_exact_ones():
    rng = np.random.default_rng(11)
    X, Y, F, C = chain_truth(rng, 4)
    # The estimator returned poses 1 and 3 turned by a half turn about the transducer axis.
    C_read = [C[0], C[1] @ HALF_TURN, C[2], C[3] @ HALF_TURN]
    naive = calibrate(F, C_read)
    assert naive.max_rotation_residual_deg > 10  # one rigid chain cannot explain them as given
    cal = calibrate_half_turns(F, C_read)
    np.testing.assert_allclose(cal.T_flange_transducer, X, atol=1e-6)
    np.testing.assert_allclose(cal.T_carm_base, Y, atol=1e-6)
    assert cal.max_rotation_residual_deg < 1e-6


def test_the_nominal_mount_picks_the_global_half_turn():
    rng = np.random.default_rng(12)
    X, Y, F, C = chain_truth(rng, 4)
    flipped_all = [c @ HALF_TURN for c in C]
    without = calibrate_half_turns(F, flipped_all)
    np.testing.assert_allclose(without.T_flange_transducer, X @ HALF_TURN, atol=1e-6)
    # A nominal mount a few degrees off the true one chooses the reading near it.
    nominal = X @ g.make_transform(g.matrix_from_rotvec([0.03, -0.02, 0.05]), [1.0, 2.0, -1.0])
    cal = calibrate_half_turns(F, flipped_all, nominal_T_flange_transducer=nominal)
    np.testing.assert_allclose(cal.T_flange_transducer, X, atol=1e-6)
    # Either reading puts the focal point (the transducer origin) at the same place.
    np.testing.assert_allclose(without.T_flange_transducer[:3, 3], cal.T_flange_transducer[:3, 3], atol=1e-6)


def test_degenerate_motions_are_refused_by_name():
    rng = np.random.default_rng(13)
    X, Y, F, C = chain_truth(rng, 3)
    F_same = [F[0]] * 3
    with pytest.raises(DegenerateMotionError, match="T_base_flange_list"):
        calibrate_half_turns(F_same, [Y @ f @ X for f in F_same])
    with pytest.raises(ValueError, match="nominal_T_flange_transducer"):
        calibrate_half_turns(F, C, nominal_T_flange_transducer=np.zeros((4, 4)))


def test_tcp_for_target_puts_the_focal_point_on_the_target_pointing_down():
    rng = np.random.default_rng(14)
    X, Y, F, C = chain_truth(rng, 4)
    cal = calibrate(F, C)
    R = target_orientation(cal)
    np.testing.assert_allclose(R[:, 2], -DOWN, atol=1e-12)  # +z (towards the transducer) points up
    target = np.array([5.0, -3.0, 12.0])
    T_base_tcp = tcp_for_target(cal, target, R)
    # The flange that carries that TCP, through the true chain, holds the transducer's focal point
    # (its origin) on the target.
    T_carm_transducer = Y @ T_base_tcp @ np.linalg.inv(cal.T_flange_transducer) @ X
    np.testing.assert_allclose(T_carm_transducer[:3, 3], target, atol=1e-6)
    np.testing.assert_allclose(T_carm_transducer[:3, :3], R, atol=1e-9)
    with pytest.raises(TypeError, match="calibration must be a HandEyeCalibration"):
        target_orientation("calibration.json")
