"""Automatic positioning of the focal point on a target (§II-D, Fig. 2 step 3): the TCP put on a
CBCT target with the transducer pointing down, and the true set-up at that pose for the 3-D figure.
Transforms are 4x4 ``T_<to>_<from>`` in mm (C-arm frame: LPS).
"""

from __future__ import annotations

import numpy as np

from histostudy.calibration import DOWN, HandEyeCalibration, target_orientation, tcp_for_target
from histostudy.geometry import invert_transform
from histostudy.robot import Robot, inverse_kinematics_closest

from .setup import GroundTruth, start_joints

# DOWN, target_orientation and tcp_for_target live in histostudy.calibration.targeting; named here too
# because the study's users have imported them from here.
__all__ = ["DOWN", "position_for_target", "scene_at_target", "target_orientation", "tcp_for_target"]


def position_for_target(robot: Robot, calibration: HandEyeCalibration, target_mm, R_carm_transducer,
                        T_flange_tcp=None, *, speed_mm_s: float = 250.0) -> np.ndarray:
    """Automatic positioning (§II-D, Fig. 2 step 3): set the TCP (default: the estimated focal
    point) and move it onto ``target_mm`` (C-arm frame) with the transducer orientation
    ``R_carm_transducer``. The robot checks the pose (workspace, reach, inverse kinematics) before
    it moves and raises (:class:`~histostudy.robot.WorkspaceViolation`,
    :class:`~histostudy.robot.UnreachablePoseError`) without moving. Returns the commanded
    ``T_base_tcp``."""
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    target = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_mm must be 3 finite numbers (C-arm frame, mm), got {target_mm!r}")
    T_ft = calibration.T_flange_transducer if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    T_base_tcp = tcp_for_target(calibration, target, R_carm_transducer, T_ft)
    robot.set_tcp(T_ft)
    robot.move_linear(T_base_tcp, speed_mm_s)
    return T_base_tcp


def scene_at_target(truth: GroundTruth, calibration: HandEyeCalibration, target_mm, R_carm_transducer) -> dict:
    """The physical set-up with the robot at the treatment's start, for a 3-D scene
    (:func:`histostudy.reporting.viz.targeting_scene`).

    The robot is commanded (:func:`tcp_for_target`, calibrated chain) to put the estimated focal
    point on ``target_mm`` (C-arm mm) with the orientation ``R_carm_transducer``; what it reaches is
    drawn from the ground truth: its joints (the inverse-kinematics solution closest to the start
    configuration of :func:`run_targeting_experiment`; the repeatability noise left out), its true
    base and the true transducer on its flange. Returns a dict of 4x4 transforms (mm) and joints
    (rad): ``T_carm_base``, ``joints_rad`` (6,), ``T_base_flange``, ``T_carm_transducer`` (the TRUE
    transducer pose) and ``T_carm_phantom``.
    """
    if not isinstance(truth, GroundTruth):
        raise TypeError(f"truth must be a GroundTruth, got {type(truth).__name__}")
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    target = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_mm must be 3 finite numbers (C-arm frame, mm), got {target_mm!r}")
    R = np.asarray(R_carm_transducer, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"R_carm_transducer must be a 3x3 rotation, got shape {R.shape}")
    F_cmd = tcp_for_target(calibration, target, R) @ invert_transform(calibration.T_flange_transducer)
    q = inverse_kinematics_closest(F_cmd, start_joints(truth))
    return {"T_carm_base": truth.T_carm_base.copy(), "joints_rad": q, "T_base_flange": F_cmd,
            "T_carm_transducer": truth.T_carm_transducer(F_cmd), "T_carm_phantom": truth.T_carm_phantom.copy()}
