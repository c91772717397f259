"""The targeting study's hand-eye calibration (§II-C; eq. 3-5 for the pose estimates): the
preprogrammed flange poses, a biplane pair rendered from the true pose at each, the poses
estimated and AX = XB solved, its residuals checked against a bound. Transforms ``T_<to>_<from>``,
mm (base frame: the robot's; C-arm frame: LPS).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from histostudy.calibration import (
    HALF_TURN,
    R_BASE_FLANGE_DOWN,
    DegenerateMotionError,
    HandEyeCalibration,
    calibrate_half_turns,
)
from histostudy.geometry import make_transform, matrix_from_rotvec, rotation_about_axis
from histostudy.imaging import View, random_background, render_frame
from histostudy.learning import OracleOrientation
from histostudy.pose import PoseEstimationError, estimate_pose
from histostudy.robot import Robot
from histostudy.transducer import TransducerModel

from .robots import InaccurateArm, reported_flange_pose
from .setup import GroundTruth, TargetingError, TargetingStudyConfig

# HALF_TURN lives in histostudy.calibration.targeting; named here too for the study's users.
__all__ = ["HALF_TURN", "calibrate_robot", "calibration_poses", "config_focal_flange"]

def calibration_poses(rng: np.random.Generator, config: TargetingStudyConfig, truth: GroundTruth) -> list[np.ndarray]:
    """The preprogrammed flange poses of the calibration (§II-C).

    Pose k tilts the tool axis by ``calibration_tilt_deg`` about the horizontal axis at azimuth
    ``2 pi k / n`` (plus up to ±0.3 rad), turns the transducer about its axis by up to
    ``calibration_axial_deg`` (alternating sign), and puts the designed focal point within
    ``calibration_offset_mm`` of the start point: the motions' rotation axes differ, which AX = XB needs.

    Args:
        rng: the experiment's pose stream.
        config: the study's parameters (``n_calibration_poses`` and the three above).
        truth: the experiment's ground truth (the nominal mount and the start point).

    Returns:
        ``n_calibration_poses`` poses ``T_base_flange`` (4x4, mm; base frame).
    """
    n = int(config.n_calibration_poses)
    tilt = np.radians(config.calibration_tilt_deg)
    fmax = np.radians(config.calibration_axial_deg)
    focal_local = config_focal_flange(truth.T_flange_transducer_nominal)
    out = []
    for k in range(n):
        phi = 2 * np.pi * k / n + rng.uniform(-0.3, 0.3)
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        spin = (1 if k % 2 == 0 else -1) * rng.uniform(0.3, 1.0) * fmax
        R = R_BASE_FLANGE_DOWN @ matrix_from_rotvec(tilt * axis) @ rotation_about_axis([0, 0, 1], spin)
        focal = truth.start_focal_base_mm + rng.uniform(-config.calibration_offset_mm, config.calibration_offset_mm, 3)
        out.append(make_transform(R, focal - R @ focal_local))
    return out


def config_focal_flange(T_flange_transducer) -> np.ndarray:
    """The focal point (transducer origin) in the flange frame."""
    return np.asarray(T_flange_transducer, float)[:3, 3].copy()

def calibrate_robot(robot: Robot, truth: GroundTruth, config: TargetingStudyConfig, *, pose_model: TransducerModel,
                    render_model: TransducerModel, physical: TransducerModel, views: Sequence[View],
                    rng_pose: np.random.Generator, rng_scene: np.random.Generator, rng_render: np.random.Generator,
                    rng_est: np.random.Generator, segmenter=None, orientation=None,
                    estimator_views: Sequence[View] | None = None,
                    acquisition_views=None) -> tuple[HandEyeCalibration, pd.DataFrame]:
    """§II-C on ``robot``: move to the preprogrammed poses, estimate the transducer pose from a
    biplane pair rendered from the true pose at each, calibrate, check the residuals.

    ``segmenter`` / ``orientation``: the pose estimate's stages (e.g. the shipped U-Net and VGG19
    from :func:`histostudy.study.pose.experiments.study_stages`); None: the config's oracle
    segmenter and the oracle orientation.

    ``views`` make the frames (the C-arm's true geometry); ``estimator_views``, when given, are
    what the estimator is told (a lab's calibration of the C-arm); ``acquisition_views(k, views)``,
    when given, the views it is told at pose ``k`` (a lab's per-acquisition C-arm reproducibility).
    The encoders' reading (:func:`~._robots.reported_flange_pose`) enters the calibration; the frames
    are rendered where the flange really is (an :class:`~._robots.InaccurateArm`'s ``flange_pose()``).

    A pair whose estimate fails its verdict is acquired again (new splats and noise), up to
    ``config.calibration_acquisitions`` pairs per pose; where none is refused the draws are those of
    one pair per pose.

    Returns the checked calibration and one row per pose (the true and estimated focal points,
    the pose-estimation error, the pairs acquired). Raises :class:`TargetingError` when every pair of
    a pose fails its verdict and :class:`~histostudy.calibration.CalibrationError` beyond the
    residual bound.
    """
    estimator_views = list(views) if estimator_views is None else list(estimator_views)
    if len(estimator_views) != len(views):
        raise ValueError(f"estimator_views must hold one view per frame view ({len(views)}), "
                         f"got {len(estimator_views)}")
    robot.set_tcp(np.eye(4))  # calibration poses are flange poses
    scene = None if config.background == "none" else random_background(rng_scene, config.background)
    segmenter = config.segmenter() if segmenter is None else segmenter
    orientation = OracleOrientation() if orientation is None else orientation
    F, C, rows = [], [], []
    for k, T_cmd in enumerate(calibration_poses(rng_pose, config, truth)):
        robot.move_linear(T_cmd)
        F_k = reported_flange_pose(robot)  # what the encoders say
        # only a simulated inaccurate arm knows where its flange really is; any other robot is its reading
        T_true = truth.T_carm_transducer(robot.flange_pose() if isinstance(robot, InaccurateArm) else F_k)
        told = estimator_views if acquisition_views is None else acquisition_views(k, estimator_views)
        for acquisition in range(1, config.calibration_acquisitions + 1):
            frames = [render_frame(render_model, T_true, v, rng=rng_render, physical=physical, background=scene,
                                   **config.frame_kwargs()).with_view(given) for v, given in zip(views, told)]
            try:
                res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                    rng=np.random.default_rng(rng_est.integers(2**63)), mode=config.pose_mode)
                break
            except PoseEstimationError as exc:
                if acquisition == config.calibration_acquisitions:
                    raise TargetingError(f"calibration pose {k}: the pose estimates of all {acquisition} pairs "
                                         f"acquired failed their verdict (the last: {exc})") from exc
        F.append(F_k)
        C.append(res.T_carm_transducer)
        true_focal = T_true[:3, 3]
        rows.append({"pose": k, **{f"true_{a}": v for a, v in zip("xyz", true_focal)},
                     **{f"pred_{a}": v for a, v in zip("xyz", res.focal_point_mm)},
                     "pose_error_mm": float(np.linalg.norm(res.focal_point_mm - true_focal)),
                     "acquisitions": acquisition,
                     "seconds": res.timings_s.get("total", np.nan)})
    try:
        cal = calibrate_half_turns(F, C, nominal_T_flange_transducer=truth.T_flange_transducer_nominal)
    except DegenerateMotionError as exc:
        raise TargetingError(f"the calibration poses do not determine the hand-eye calibration: {exc}") from exc
    cal.check(config.max_focal_residual_mm, config.max_rotation_residual_deg)
    return cal, pd.DataFrame(rows)
