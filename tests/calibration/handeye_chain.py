"""Shared by the calibration tests: an exact synthetic robot/C-arm chain and OpenCV's Daniilidis on it.

Independent of the code under test: the chain is built from known X and Y, OpenCV is
``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_DANIILIDIS)``.
"""

import cv2
import numpy as np

from histostudy.geometry import transforms as g


def chain_truth(rng, n_poses):
    """A random true mounting X = T_flange_transducer, cart Y = T_carm_base, flange poses F_i and
    the exact pose estimates C_i = Y F_i X."""
    X = g.random_transform(rng, 200.0)
    Y = g.random_transform(rng, 800.0)
    F = [g.random_transform(rng, 400.0) for _ in range(n_poses)]
    C = [Y @ Fi @ X for Fi in F]
    return X, Y, F, C


def opencv_eye_in_hand(F, C):
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


def opencv_eye_to_hand(F, C):
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


def rotation_error_deg(R1, R2):
    return np.degrees(g.rotation_angle(R1.T @ R2))
