"""One targeting experiment and the study of several (§II-C, §II-D, §II-E.4, §III): the ground truth
drawn, the hand-eye calibration, the pre-treatment CBCT and target, the treatment (once as the
paper, once bias-corrected) and the errors along the commanded depth/TB/LR axes. C-arm frame (LPS),
mm; rotations in degrees (docs/targeting-study.md).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.calibration import HandEyeCalibration
from histostudy.geometry import invert_transform, make_transform, rotation_angle
from histostudy.imaging import PhantomSpec, View, check_target, random_target, simulate_cbct
from histostudy.transducer import TransducerModel
from histostudy.treatment import TreatmentZone, ZoneSegmentation

from ..pose.geometry import DIRECTIONS, transducer_axes
from ._calibration import calibrate_robot
from ._positioning import target_orientation, tcp_for_target
from ._treatment import learn_bubble_bias, phantom_for, treat_zone
from .robots import robot_seed, rtde_robot, sim_robot
from .setup import GroundTruth, TargetingStudyConfig, draw_ground_truth, start_joints

__all__ = ["calibration_errors", "run_targeting_experiment", "run_targeting_study", "zone_errors"]


def zone_errors(prefix: str, seg: ZoneSegmentation, target: np.ndarray, R_des: np.ndarray, radius: float) -> dict:
    """The row entries of one treated zone (§II-E.4), keys prefixed by ``prefix``.

    Args:
        prefix: ``""`` (as the paper) or ``"corr_"`` (bias-corrected).
        seg: the zone's segmentation.
        target: the intended target (3, C-arm frame, mm).
        R_des: the commanded transducer orientation (3x3; transducer -> C-arm).
        radius: the planned radius (mm).

    Returns:
        ``err_depth``/``err_tb``/``err_lr`` (the centroid minus the target along ``R_des``' axes),
        ``err_euclidean``, ``radius_mm`` and ``radius_err_mm`` (the fitted sphere), ``centroid_x/y/z``
        (C-arm frame); all mm.
    """
    err = seg.centroid_mm - target
    axes = transducer_axes(make_transform(R_des))
    row = {f"{prefix}err_{d}": float(err @ axes[d]) for d in DIRECTIONS}
    row[f"{prefix}err_euclidean"] = float(np.linalg.norm(err))
    row[f"{prefix}radius_mm"] = float(seg.sphere_radius_mm)
    row[f"{prefix}radius_err_mm"] = float(seg.sphere_radius_mm - radius)
    row.update({f"{prefix}centroid_{a}": v for a, v in zip("xyz", seg.centroid_mm)})
    return row


def calibration_errors(calibration: HandEyeCalibration, calibration_rows: pd.DataFrame, truth: GroundTruth) -> dict:
    """The row entries of the calibration (``cal_*``).

    Args:
        calibration: the hand-eye calibration.
        calibration_rows: its poses' rows (:func:`~histostudy.study.targeting._calibration.calibrate_robot`).
        truth: the experiment's ground truth.

    Returns:
        The residuals (mm, deg), the mean pose-estimation error of its poses (mm), and its errors
        against the truth: rotation (deg) and translation (mm) of X = ``T_flange_transducer`` and
        Y = ``T_carm_base``.
    """
    cal, cal_rows, X = calibration, calibration_rows, calibration.T_flange_transducer
    return dict(cal_rms_focal_residual_mm=cal.rms_focal_residual_mm,
                cal_max_rotation_residual_deg=cal.max_rotation_residual_deg,
                cal_pose_error_mm=float(cal_rows["pose_error_mm"].mean()),
                cal_X_rotation_deg=float(np.degrees(rotation_angle(X[:3, :3].T @ truth.T_flange_transducer[:3, :3]))),
                cal_X_translation_mm=float(np.linalg.norm(X[:3, 3] - truth.T_flange_transducer[:3, 3])),
                cal_Y_rotation_deg=float(np.degrees(rotation_angle(cal.T_carm_base[:3, :3].T @ truth.T_carm_base[:3,
                                                                                                                 :3]))),
                cal_Y_translation_mm=float(np.linalg.norm(cal.T_carm_base[:3, 3] - truth.T_carm_base[:3, 3])))


def run_targeting_experiment(config: TargetingStudyConfig, seq: np.random.SeedSequence, *,
                             pose_model: TransducerModel, render_model: TransducerModel, physical: TransducerModel,
                             views: Sequence[View], robot_factory=None, keep_volumes: bool = False,
                             experiment: int = 0, segmenter=None, orientation=None,
                             estimator_views: Sequence[View] | None = None, acquisition_views=None) -> dict:
    """One targeting experiment from the seed sequence ``seq`` (docs/targeting-study.md): the ground
    truth drawn, the calibration, the pre-treatment CBCT and target, the treatment (and, with
    ``config.bias_correction``, the calibration treatment and the corrected one).

    Args:
        config: the study's parameters.
        seq: the experiment's seed sequence (spawned from a copy: the same ``seq`` gives the same experiment).
        pose_model: the digital model the pose is estimated with.
        render_model: the model frames are rendered from.
        physical: the physical transducer.
        views: the views that make the frames (the C-arm's true geometry).
        robot_factory: ``(seed, initial_joints_rad) -> context manager yielding a Robot``; None:
            :func:`~histostudy.study.targeting.robots.sim_robot`.
        keep_volumes: also return the CBCTs, the segmentation and the calibration under ``"_volumes"``.
        experiment: the experiment's index (recorded).
        segmenter: the calibration's segmentation stage; None: the config's oracle.
        orientation: its orientation source; None: the oracle.
        estimator_views: the views the estimator is told (a lab's calibration); None: ``views``.
        acquisition_views: ``(k, views) -> views`` told at calibration pose ``k``; None: as given.

    Returns:
        One flat row: target, diameter, the zone errors (:func:`zone_errors`, ``corr_*`` with the
        correction), the learnt bias ``bias_learnt_*``, the calibration's ``cal_*``
        (:func:`calibration_errors`, ``cal_error_at_target_mm``), the commanded axes ``axis_<d>_<x|y|z>``,
        moves and points (mm, deg).

    Raises:
        TypeError: ``seq`` is not a SeedSequence.
        TargetingError: a calibration pose's estimate failed its verdict, or degenerate motions.
        CalibrationError: the calibration's residuals beyond the config's bound.
    """
    robot_factory = sim_robot(config) if robot_factory is None else robot_factory
    if not isinstance(seq, np.random.SeedSequence):
        raise TypeError(f"seq must be a numpy.random.SeedSequence, got {type(seq).__name__}")
    # SeedSequence.spawn is stateful: spawn from a copy, so the same seq always gives the same
    # experiment (the "both" robots run one seq twice).
    fresh = np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key, pool_size=seq.pool_size)
    (s_truth, s_pose, s_scene, s_render, s_est, s_robot, s_target, s_cbct) = fresh.spawn(8)
    rng_truth = np.random.default_rng(s_truth)
    truth = draw_ground_truth(rng_truth, config)
    rng_target = np.random.default_rng(s_target)
    rng_cbct = np.random.default_rng(s_cbct)
    diameter = float(rng_target.choice(np.asarray(config.zone_diameters_mm, float)))
    radius = 0.5 * diameter
    phantom, roi = phantom_for(truth, config)
    pre = simulate_cbct(phantom, rng_cbct, blur_sigma_mm=config.cbct_blur_mm, noise_sd_hu=config.cbct_noise_hu,
                        voxel_mm=config.cbct_voxel_mm)
    border = radius + 4.0  # the zone and half the segmentation window inside the phantom
    target = check_target(random_target(rng_target, PhantomSpec(), truth.T_carm_phantom, border_mm=border),
                          PhantomSpec(), truth.T_carm_phantom, volume=pre, margin_mm=radius)
    zone = TreatmentZone(target, diameter)
    row = {"experiment": experiment, "diameter_mm": diameter, **{f"target_{a}": v for a, v in zip("xyz", target)}}
    # The operator jogged the flange pointing down over the phantom: the robot starts there.
    q_start = start_joints(truth)
    with robot_factory(robot_seed(s_robot),
                       q_start) as robot, tempfile.TemporaryDirectory(prefix="histostudy-target-") as tmp:
        cal, cal_rows = calibrate_robot(robot, truth, config, pose_model=pose_model, render_model=render_model,
                                        physical=physical, views=views, rng_pose=np.random.default_rng(s_pose),
                                        rng_scene=np.random.default_rng(s_scene),
                                        rng_render=np.random.default_rng(s_render),
                                        rng_est=np.random.default_rng(s_est),
                                        segmenter=segmenter, orientation=orientation,
                                        estimator_views=estimator_views, acquisition_views=acquisition_views)
        R_des = target_orientation(cal)
        axes = transducer_axes(make_transform(R_des))
        row.update({f"axis_{d}_{a}": float(v) for d in DIRECTIONS for a, v in zip("xyz", axes[d])})
        X = cal.T_flange_transducer
        row.update(calibration_errors(cal, cal_rows, truth))
        F_cmd = tcp_for_target(cal, target, R_des) @ invert_transform(X)
        row["cal_error_at_target_mm"] = float(np.linalg.norm(truth.T_carm_transducer(F_cmd)[:3, 3] - target))

        bias_local = np.zeros(3)
        if config.bias_correction:
            bias_local = learn_bubble_bias(robot, truth, cal, config, R_des, X, phantom, roi, physical, rng_target,
                                           rng_cbct, Path(tmp) / "calibration_treatment.json")
        row.update({f"bias_learnt_{a}": v for a, v in zip(("lr", "tb", "depth"), (bias_local[0], bias_local[1],
                                                                                  -bias_local[2]))})

        seg, post, info = treat_zone(robot, truth, cal, config, zone, R_des, X, phantom, roi, physical, rng_cbct,
                                     Path(tmp) / "treatment.json")
        row.update(zone_errors("", seg, target, R_des, radius))
        row["n_points"] = info["n_points"]
        row["cloud_err_euclidean"] = float(np.linalg.norm(info["cloud_centroid_mm"] - target))
        if config.bias_correction:
            X_corr = X @ make_transform(None, bias_local)
            seg_c, post_c, info_c = treat_zone(robot, truth, cal, config, zone, R_des, X_corr, phantom, roi, physical,
                                               rng_cbct, Path(tmp) / "treatment_corrected.json")
            row.update(zone_errors("corr_", seg_c, target, R_des, radius))
            row["corr_cloud_err_euclidean"] = float(np.linalg.norm(info_c["cloud_centroid_mm"] - target))
        row["moves"] = robot.state().moves_completed
        row["robot_final_tcp_mm"] = robot.tcp_pose()[:3, 3].tolist()
    row["physical_focal_offset_mm"] = float(np.linalg.norm(physical.focal_point_mm))
    if keep_volumes:
        row["_volumes"] = {"pre": pre, "post": post, "segmentation": seg, "R_des": R_des, "target": target,
                           "calibration": cal, "calibration_rows": cal_rows, "truth": truth}
    return row


def run_targeting_study(config: TargetingStudyConfig, *, pose_model: TransducerModel, render_model: TransducerModel,
                        physical: TransducerModel, views: Sequence[View], seed: int, robot: str = "sim",
                        keep_volumes: bool = False, progress: Callable[[str], None] | None = None,
                        segmenter=None, orientation=None, estimator_views: Sequence[View] | None = None,
                        experiments: Sequence[int] | None = None) -> pd.DataFrame:
    """Run ``config.n_experiments`` experiments (:func:`run_targeting_experiment`), each from its
    child of ``SeedSequence(seed)``.

    Args:
        config: the study's parameters.
        pose_model: the digital model the pose is estimated with.
        render_model: the model frames are rendered from.
        physical: the physical transducer.
        views: the C-arm views.
        seed: the study's integer seed.
        robot: ``"sim"`` (SimulatedUR5e), ``"rtde"`` (the simulated controller through ur_rtde) or
            ``"both"`` (each experiment on both, from the same seeds).
        keep_volumes: keep the volumes (column ``_volumes``).
        progress: called with a line per experiment; None: silent.
        segmenter: the calibration's segmentation stage (e.g. of
            :func:`~histostudy.study.pose.experiments.study_stages`); None: the config's oracle.
        orientation: its orientation source; None: the oracle.
        estimator_views: the views the estimator is told; None: ``views``.
        experiments: run only these experiment indices (each keeps its seeds).

    Returns:
        One row per (experiment, robot): ``robot`` and :func:`run_targeting_experiment`'s columns.

    Raises:
        ValueError: an unknown ``robot``.
        TargetingError, CalibrationError: as :func:`run_targeting_experiment`.
    """
    robots = {"sim": ("sim",), "rtde": ("rtde",), "both": ("sim", "rtde")}.get(robot)
    if robots is None:
        raise ValueError(f"robot must be 'sim', 'rtde' or 'both', got {robot!r}")
    factories = {"sim": sim_robot(config), "rtde": rtde_robot(config)}
    rows = []
    wanted = None if experiments is None else {int(e) for e in experiments}
    for e, seq in enumerate(np.random.SeedSequence(seed).spawn(config.n_experiments)):
        if wanted is not None and e not in wanted:
            continue
        for name in robots:
            row = run_targeting_experiment(config, seq, pose_model=pose_model, render_model=render_model,
                                           physical=physical, views=views, robot_factory=factories[name],
                                           keep_volumes=keep_volumes, experiment=e, segmenter=segmenter,
                                           orientation=orientation, estimator_views=estimator_views)
            rows.append({"robot": name, **row})
            if progress:
                progress(f"experiment {e + 1}/{config.n_experiments} ({name}): {row['err_euclidean']:.2f} mm")
    return pd.DataFrame(rows)
