"""Notebook 05: the paper's automated targeting study (§II-C, §II-D, §II-E.4, §III) on synthetic data.

One experiment, as in the lab, in four stages:

1. **Ground truth set-up** (what the lab had but did not know): the robot base placed beside the
   table (``T_carm_base``, drawn), the transducer mounted below the flange (``T_flange_transducer``:
   focal point 200-300 mm along the tool axis plus a few mm / degrees of mounting error, drawn),
   the *physical* transducer (its acoustic focal point differs from the digital model's) and a
   bubble-cloud offset from it (configurable, default 0).
2. **Calibration** (§II-C): the robot moves the flange to ``n_calibration_poses`` preprogrammed
   poses about a start pose above the phantom (the transducer pointing down, tilted about
   different horizontal axes and turned about its own axis so that the motions determine
   AX = XB); at each the robot's measured ``T_base_flange`` is read and a biplane pair is rendered
   from the TRUE transducer pose (``T_carm_base_true @ T_base_flange_reached @
   T_flange_transducer_true``); the pose is estimated (fast mode; the stages given, in notebook 05
   the shipped U-Net and VGG19, otherwise the Table I-degraded oracle segmenter and the oracle
   orientation) and :func:`histostudy.calibration.handeye.calibrate` run on the pairs.
   Its residuals are checked against a stated bound (:meth:`HandEyeCalibration.check`): targeting
   refuses to run on a calibration that fails it.
3. **Pre-treatment CBCT** of the layered phantom; a target picked inside it with the whole zone
   (20 or 25 mm) and the segmentation window inside the phantom.
4. **Automatic positioning and treatment**: the TCP is set to the estimated focal point, the
   transducer pointed down (its propagation along the world's posterior +y, the axial rotation of
   the flange pointing straight down), the robot moved (it checks reach and workspace before it
   moves), the zone treated (:func:`histostudy.treatment.plan_treatment` /
   :func:`~histostudy.treatment.execute_treatment`, journal in a temporary folder), the bubble
   clouds placed at the TRUE focal points of the physical transducer for the reached robot
   poses (plus the offset), the layers mixed, a post-treatment CBCT simulated and the zone
   segmented (:func:`histostudy.treatment.zone.segment_treatment_zone`, the stand-in for the manual
   annotation).

Errors (§II-E.4): Euclidean distance between the intended target and the segmented zone's
centroid; its components along depth/TB/LR (the commanded transducer axes at the target); the
segmented sphere radius against the planned radius; and the calibration against the ground
truth (rotation and translation of ``T_flange_transducer`` and ``T_carm_base``, and the
calibration's error at the target: where the true chain puts the focal point for the commanded
flange pose).

**Bias correction** (§IV: "this could be further improved by including the pose estimation bias
during the calibration"). Fluoroscopy cannot see the bias: the calibration's own residuals are
zero-mean by construction (its translation is the least-squares fit to the estimated focal
points), and the offset between the digital model's focal point and the bubble cloud
(manufacturing, aberration) moves no transducer feature. So the bias is learnt as the
conventional workflow's test pulse does (§II-A step 3), with one **calibration treatment**: after
the hand-eye calibration, a test zone is treated in a separate calibration phantom, its
post-treatment CBCT segmented, and the offset of its centroid from the intended target expressed
in the transducer frame, ``b = R_des^T (centroid - target)``. The corrected TCP is the estimated
focal point moved by ``b`` (``T_flange_tcp = X_est @ Trans(b)``): aiming that TCP at a target puts
the bubble cloud where the test lesion says it lands. Each experiment treats its target twice
(two identical phantoms, the same pre-treatment CBCT and target): once as the paper did (no
correction) and once with the corrected TCP, so both are reported on the same target.

The robot is a :class:`~histostudy.robot.SimulatedUR5e` or an :class:`~histostudy.robot.RTDERobot`
driving the simulated UR controller through the real ``ur_rtde`` client (:func:`rtde_robot`); both
take the same integer seed for the repeatability noise (the controller's ``--seed``), so the same
study seed gives the same moves and the same numbers on either (up to the float round trip of the
metre/axis-angle boundary, far below 1e-6 mm).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from histostudy.calibration import R_BASE_FLANGE_DOWN, HandEyeCalibration, calibrate
from histostudy.geometry import (invert_transform, make_transform, matrix_from_rotvec, rotation_about_axis,
                                 rotation_angle)
from histostudy.imaging import (PhantomSpec, View, Volume, check_target, phantom_mask, phantom_volume,
                                random_background, random_target, render_frame, simulate_cbct)
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import PoseEstimationError, estimate_pose
from histostudy.robot import HOME_JOINTS_RAD, Robot, SimulatedUR5e, inverse_kinematics_closest
from histostudy.transducer import TransducerModel
from histostudy.treatment import (STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM, TreatmentZone, ZoneSegmentation,
                                  execute_treatment, plan_treatment, scan_treated_zone)
from .pose_estimation import DIRECTIONS, _mean_sd, transducer_axes

__all__ = [
    "GroundTruth",
    "TargetingError",
    "TargetingStudyConfig",
    "calibrate_robot",
    "calibration_poses",
    "draw_ground_truth",
    "robot_seed",
    "rtde_robot",
    "run_targeting_experiment",
    "plot_target_slices",
    "position_for_target",
    "run_targeting_study",
    "scene_at_target",
    "sim_robot",
    "summary",
    "target_orientation",
    "targeting_values",
    "tcp_for_target",
]

#: A half turn about the transducer's z axis: the aperture, gaps and cutout look the same after it.
HALF_TURN = np.diag([-1.0, -1.0, 1.0, 1.0])
#: World direction of propagation with the transducer pointing down (LPS: +y is posterior).
DOWN = np.array([0.0, 1.0, 0.0])


class TargetingError(RuntimeError):
    """The targeting study cannot go on (a calibration outside its bound, a failed pose estimate)."""


@dataclass(frozen=True)
class TargetingStudyConfig:
    """Parameters of the targeting study (defaults: the standard profile's, the paper's set-up).

    Attributes:
        n_experiments: phantom experiments (paper: 6).
        zone_diameters_mm: target sphere diameters drawn per experiment (paper: 20 or 25 mm).
        n_calibration_poses: robot poses of the hand-eye calibration (paper: 4; >= 3).
        calibration_tilt_deg: tilt of the tool axis from vertical at the calibration poses (each
            about a different horizontal axis).
        calibration_axial_deg: the transducer is also turned about its axis by up to this.
        calibration_offset_mm: focal points of the calibration poses within ± this of the start.
        background: scene behind the transducer at calibration (``"phantom"``: the water bath and
            phantom; ``"none"``: no scene, for fast tests).
        photons_per_pixel, n_splats, splat_sigma_mm: fluoroscopy rendering (§II-B.2).
        degradation: ``"table1"`` (oracle segmenter errs as the paper's U-Net) or ``"none"``.
        pose_mode: refinement mode of :func:`histostudy.pose.estimate_pose`.
        max_focal_residual_mm, max_rotation_residual_deg: the calibration's bound; targeting
            refuses to run beyond it.
        base_distance_mm: range of the horizontal distance of the robot base from the isocentre.
        base_yaw_deg: the base turned about its vertical axis by up to ± this.
        base_tilt_deg: SD of the base's tilt from level (floor, cart).
        flange_to_focal_mm: range of the design distance flange -> focal point along the tool axis.
        mount_translation_sd_mm, mount_rotation_sd_deg: mounting error of the transducer (per axis).
        phantom_jitter_mm: phantom centre uniform within ± this of the isocentre, per axis.
        phantom_voxel_mm: grid of the true phantom (partial volumes, bubble clouds).
        cbct_voxel_mm, cbct_blur_mm, cbct_noise_hu: the simulated CBCT (§II-D).
        treatment_spacing_mm: lattice spacing of the plan (LR, TB, depth).
        treatment_inset_mm: the plan's ellipsoid inset (:data:`histostudy.treatment.STUDY_PLAN_INSET_MM`).
        pulses_per_point: per focal location (§II-D).
        robot_repeatability_mm: landing noise radius of the UR5e (±0.03 mm).
        bubble_offset_mm: bubble cloud offset from the physical focal point, transducer frame.
        bias_correction: run the calibration treatment and the corrected targeting.
        bias_test_diameter_mm: diameter of the calibration treatment's test zone.
    """

    n_experiments: int = 6
    zone_diameters_mm: tuple = (20.0, 25.0)
    n_calibration_poses: int = 4
    calibration_tilt_deg: float = 15.0
    calibration_axial_deg: float = 30.0
    calibration_offset_mm: float = 15.0
    background: str = "phantom"
    photons_per_pixel: float = 5e4
    n_splats: int = 16
    splat_sigma_mm: float = 0.5
    degradation: str = "table1"
    pose_mode: str = "fast"
    max_focal_residual_mm: float = 2.0
    max_rotation_residual_deg: float = 1.0
    base_distance_mm: tuple = (500.0, 650.0)
    base_yaw_deg: float = 15.0
    base_tilt_deg: float = 0.5
    flange_to_focal_mm: tuple = (200.0, 300.0)
    mount_translation_sd_mm: float = 2.0
    mount_rotation_sd_deg: float = 1.0
    phantom_jitter_mm: float = 5.0
    phantom_voxel_mm: float = 0.5
    cbct_voxel_mm: float = 1.0
    cbct_blur_mm: float = 0.5
    cbct_noise_hu: float = 20.0
    treatment_spacing_mm: tuple = STUDY_PLAN_SPACING_MM
    treatment_inset_mm: tuple = STUDY_PLAN_INSET_MM
    pulses_per_point: int = 50
    robot_repeatability_mm: float = 0.03
    bubble_offset_mm: tuple = (0.0, 0.0, 0.0)
    bias_correction: bool = True
    bias_test_diameter_mm: float = 20.0

    def __post_init__(self):
        if isinstance(self.n_experiments, bool) or int(self.n_experiments) != self.n_experiments or self.n_experiments < 1:
            raise ValueError(f"n_experiments must be an integer >= 1, got {self.n_experiments!r}")
        if int(self.n_calibration_poses) != self.n_calibration_poses or self.n_calibration_poses < 3:
            raise ValueError(f"n_calibration_poses must be an integer >= 3 (hand-eye needs 2 motions), "
                             f"got {self.n_calibration_poses!r}")
        if not self.zone_diameters_mm or any(not (np.isfinite(d) and 0 < d <= 30) for d in self.zone_diameters_mm):
            raise ValueError(f"zone_diameters_mm must hold diameters in (0, 30] mm (the 50 mm phantom), "
                             f"got {self.zone_diameters_mm!r}")
        if not (np.isfinite(self.bias_test_diameter_mm) and 0 < self.bias_test_diameter_mm <= 30):
            raise ValueError(f"bias_test_diameter_mm must be in (0, 30] mm, got {self.bias_test_diameter_mm!r}")
        OracleSegmenter.named(self.degradation)  # a clear error now for an unknown name
        if self.background not in ("phantom", "abdomen", "mixed", "none"):
            raise ValueError(f"background must be 'phantom', 'abdomen', 'mixed' or 'none', got {self.background!r}")
        if self.pose_mode not in ("paper", "fast"):
            raise ValueError(f"pose_mode must be 'paper' or 'fast', got {self.pose_mode!r}")
        for name in ("base_distance_mm", "flange_to_focal_mm"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
                raise ValueError(f"{name} must be a range (lo, hi) with 0 < lo <= hi, got {getattr(self, name)!r}")
        for name in ("calibration_tilt_deg", "calibration_axial_deg", "calibration_offset_mm", "base_yaw_deg",
                     "base_tilt_deg", "mount_translation_sd_mm", "mount_rotation_sd_deg", "phantom_jitter_mm",
                     "robot_repeatability_mm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("phantom_voxel_mm", "cbct_voxel_mm", "max_focal_residual_mm", "max_rotation_residual_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        if np.asarray(self.bubble_offset_mm, float).shape != (3,):
            raise ValueError(f"bubble_offset_mm must be 3 numbers (transducer frame, mm), got {self.bubble_offset_mm!r}")

    def segmenter(self) -> OracleSegmenter:
        """The oracle segmenter of ``degradation``."""
        return OracleSegmenter.named(self.degradation)


# ---------------------------------------------------------------------------------------------
# Ground truth
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """What the lab had but did not know (mm, 4x4 ``T_<to>_<from>``).

    ``T_carm_base``: the robot base in the C-arm frame. ``T_flange_transducer``: the transducer
    (digital frame: origin at the geometric focal point) on the flange, mounting error included.
    ``T_flange_transducer_nominal``: the mount as designed (tool axis, no error), what the
    preprogrammed calibration poses are laid out with. ``T_carm_phantom``: the layered phantom.
    ``start_focal_base_mm``: where the operator jogged the focal point above the phantom before
    the preprogrammed calibration poses (base frame). ``bubble_offset_mm``: transducer frame.
    """

    T_carm_base: np.ndarray
    T_flange_transducer: np.ndarray
    T_flange_transducer_nominal: np.ndarray
    T_carm_phantom: np.ndarray
    start_focal_base_mm: np.ndarray
    bubble_offset_mm: np.ndarray

    def T_carm_transducer(self, T_base_flange) -> np.ndarray:
        """The true transducer pose for a (measured) flange pose."""
        return self.T_carm_base @ np.asarray(T_base_flange, float) @ self.T_flange_transducer


def _random_small_rotation(rng: np.random.Generator, sd_deg: float) -> np.ndarray:
    return matrix_from_rotvec(rng.normal(0.0, np.radians(sd_deg), 3))


def draw_ground_truth(rng: np.random.Generator, config: TargetingStudyConfig) -> GroundTruth:
    """Draw the set-up of one experiment (see :class:`GroundTruth`).

    The base stands beside the table on the patient's right (world -x, LPS), its z axis up (world
    -y) within ``base_tilt_deg``, turned by up to ``base_yaw_deg``, at a horizontal distance in
    ``base_distance_mm`` from the isocentre and 150-250 mm below it; the transducer hangs from the
    flange with its +z (towards the transducer) along the flange's -z, the focal point
    ``flange_to_focal_mm`` away, plus the mounting error.
    """
    # Base axes in the world: x away from the table (world -x), z up (world -y), y = z cross x; the
    # arm works in front of its home configuration (base -x), where straight moves stay regular.
    R0 = np.column_stack([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
    yaw = np.radians(rng.uniform(-config.base_yaw_deg, config.base_yaw_deg))
    R_cb = _random_small_rotation(rng, config.base_tilt_deg) @ R0 @ rotation_about_axis([0, 0, 1], yaw)
    distance = rng.uniform(*config.base_distance_mm)
    height = rng.uniform(150.0, 250.0)  # isocentre above the base
    phantom_centre = rng.uniform(-config.phantom_jitter_mm, config.phantom_jitter_mm, 3)
    # The isocentre sits at (-distance, y, height) in the base frame, y about the home pose's.
    iso_base = np.array([-distance, rng.uniform(-180.0, -80.0), height])
    T_cb = make_transform(R_cb, -R_cb @ iso_base)
    L = rng.uniform(*config.flange_to_focal_mm)
    X_nom = make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, L])
    X = X_nom @ make_transform(_random_small_rotation(rng, config.mount_rotation_sd_deg),
                               rng.normal(0.0, config.mount_translation_sd_mm, 3))
    # The phantom on the table: its layers horizontal (phantom z = world -y, up).
    T_cp = make_transform(rotation_about_axis([1, 0, 0], np.pi / 2), phantom_centre)
    start = invert_transform(T_cb) @ np.append(phantom_centre + rng.uniform(-5.0, 5.0, 3), 1.0)
    return GroundTruth(T_carm_base=T_cb, T_flange_transducer=X, T_flange_transducer_nominal=X_nom,
                       T_carm_phantom=T_cp, start_focal_base_mm=start[:3],
                       bubble_offset_mm=np.asarray(config.bubble_offset_mm, dtype=np.float64))


def calibration_poses(rng: np.random.Generator, config: TargetingStudyConfig, truth: GroundTruth) -> list[np.ndarray]:
    """The preprogrammed flange poses ``T_base_flange`` (base frame) of the calibration (§II-C).

    Pose k tilts the tool axis by ``calibration_tilt_deg`` about the horizontal axis at azimuth
    ``2 pi k / n`` (plus up to ±0.3 rad), turns the transducer about its axis by up to
    ``calibration_axial_deg`` (alternating sign), and puts the designed focal point within
    ``calibration_offset_mm`` of the start point: the rotation axes of the motions differ, which
    AX = XB needs.
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


# ---------------------------------------------------------------------------------------------
# Robots
# ---------------------------------------------------------------------------------------------


def robot_seed(seq: np.random.SeedSequence) -> int:
    """The integer seed of the robot's repeatability noise (the controller's ``--seed``)."""
    return int(seq.generate_state(1)[0])


def sim_robot(config: TargetingStudyConfig):
    """A robot factory for :func:`run_targeting_experiment`: ``SimulatedUR5e`` in process."""

    @contextlib.contextmanager
    def factory(seed: int, initial_joints_rad=HOME_JOINTS_RAD):
        robot = SimulatedUR5e(int(seed), repeatability_mm=config.robot_repeatability_mm,
                              initial_joints_rad=initial_joints_rad)
        try:
            yield robot
        finally:
            robot.close()

    return factory


_HOST_LOCK = threading.Lock()
_HOST_COUNTER = itertools.count(1)


def _loopback_host() -> str:
    """A loopback address of its own per controller (ur_rtde's ports are fixed)."""
    with _HOST_LOCK:
        k = next(_HOST_COUNTER)
    return f"127.{(os.getpid() % 200) + 30}.{(k % 250) + 1}.{(os.getpid() // 200) % 250 + 2}"


def rtde_robot(config: TargetingStudyConfig, *, command_timeout_s: float = 10.0):
    """A robot factory: the simulated UR controller in its own process on a loopback address,
    driven by :class:`~histostudy.robot.RTDERobot` through the real ``ur_rtde`` client.

    The controller's ``--seed`` is the experiment's robot seed, so its repeatability noise is
    drawn exactly as :func:`sim_robot`'s. The controller is stopped when the block ends.
    """
    from histostudy.robot import RTDERobot
    from histostudy.robot.controller import ControllerProcess

    @contextlib.contextmanager
    def factory(seed: int, initial_joints_rad=HOME_JOINTS_RAD):
        proc = ControllerProcess(_loopback_host(), "--seed", str(int(seed)),
                                 "--repeatability-mm", repr(float(config.robot_repeatability_mm)),
                                 "--initial-joints", *(repr(float(q)) for q in initial_joints_rad),
                                 max_lifetime_s=3600)
        try:
            robot = RTDERobot(proc.host, command_timeout_s=command_timeout_s)
            try:
                yield robot
            finally:
                robot.close()
        finally:
            proc.stop()

    return factory


# ---------------------------------------------------------------------------------------------
# Calibration
# ---------------------------------------------------------------------------------------------


def _resolve_half_turns(F: list[np.ndarray], C: list[np.ndarray], nominal_X: np.ndarray) -> tuple[list[np.ndarray], HandEyeCalibration]:
    """Choose per pose between an estimate and its half turn about the axis (the transducer looks
    the same; the pose estimate may return either), the combination with the smallest calibration
    residuals, then the global half turn that keeps ``T_flange_transducer`` closest to the design."""
    best = None
    for flips in itertools.product((False, True), repeat=len(C) - 1):
        Cs = [C[0]] + [c @ HALF_TURN if f else c for c, f in zip(C[1:], flips)]
        try:
            cal = calibrate(F, Cs)
        except ValueError:
            continue
        score = cal.max_rotation_residual_deg
        if best is None or score < best[0]:
            best = (score, Cs, cal)
    if best is None:
        raise TargetingError("the calibration poses do not determine the hand-eye calibration")
    _, Cs, cal = best
    flipped = [c @ HALF_TURN for c in Cs]
    cal2 = calibrate(F, flipped)
    angle = lambda c: rotation_angle(c.T_flange_transducer[:3, :3].T @ nominal_X[:3, :3])
    if angle(cal2) < angle(cal):
        return flipped, cal2
    return Cs, cal


def calibrate_robot(robot: Robot, truth: GroundTruth, config: TargetingStudyConfig, *, pose_model: TransducerModel,
                    render_model: TransducerModel, physical: TransducerModel, views: Sequence[View],
                    rng_pose: np.random.Generator, rng_scene: np.random.Generator, rng_render: np.random.Generator,
                    rng_est: np.random.Generator, segmenter=None,
                    orientation=None) -> tuple[HandEyeCalibration, pd.DataFrame]:
    """§II-C on ``robot``: move to the preprogrammed poses, estimate the transducer pose from a
    biplane pair rendered from the true pose at each, calibrate, check the residuals.

    ``segmenter`` / ``orientation``: the pose estimate's stages (e.g. the shipped U-Net and VGG19
    from :func:`histostudy.study.pose_estimation.study_stages`); None: the config's oracle
    segmenter and the oracle orientation.

    Returns the checked calibration and one row per pose (the true and estimated focal points,
    the pose-estimation error). Raises :class:`TargetingError` when a pose estimate fails its
    verdict and :class:`~histostudy.calibration.handeye.CalibrationError` beyond the residual bound.
    """
    robot.set_tcp(np.eye(4))  # calibration poses are flange poses
    scene = None if config.background == "none" else random_background(rng_scene, config.background)
    segmenter = config.segmenter() if segmenter is None else segmenter
    orientation = OracleOrientation() if orientation is None else orientation
    F, C, rows = [], [], []
    for k, T_cmd in enumerate(calibration_poses(rng_pose, config, truth)):
        robot.move_linear(T_cmd)
        F_k = robot.flange_pose()  # what the encoders say
        T_true = truth.T_carm_transducer(F_k)
        frames = [render_frame(render_model, T_true, v, rng=rng_render, physical=physical, background=scene,
                               photons_per_pixel=config.photons_per_pixel, n_splats=config.n_splats,
                               splat_sigma_mm=config.splat_sigma_mm) for v in views]
        try:
            res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                rng=np.random.default_rng(rng_est.integers(2**63)), mode=config.pose_mode)
        except PoseEstimationError as exc:
            raise TargetingError(f"calibration pose {k}: the pose estimate failed its verdict ({exc}); "
                                 "re-acquire the frames") from exc
        F.append(F_k)
        C.append(res.T_carm_transducer)
        true_focal = T_true[:3, 3]
        rows.append({"pose": k, **{f"true_{a}": v for a, v in zip("xyz", true_focal)},
                     **{f"pred_{a}": v for a, v in zip("xyz", res.focal_point_mm)},
                     "pose_error_mm": float(np.linalg.norm(res.focal_point_mm - true_focal)),
                     "seconds": res.timings_s.get("total", np.nan)})
    _, cal = _resolve_half_turns(F, C, truth.T_flange_transducer_nominal)
    cal.check(config.max_focal_residual_mm, config.max_rotation_residual_deg)
    return cal, pd.DataFrame(rows)


# ---------------------------------------------------------------------------------------------
# Positioning
# ---------------------------------------------------------------------------------------------


def target_orientation(calibration: HandEyeCalibration) -> np.ndarray:
    """``R_carm_transducer`` of the treatment: propagation straight down (world +y), the axial
    rotation the transducer has when the flange points straight down (the smallest turn from it)."""
    R0 = calibration.T_carm_base[:3, :3] @ R_BASE_FLANGE_DOWN @ calibration.T_flange_transducer[:3, :3]
    z0, z1 = R0[:, 2], -DOWN
    axis = np.cross(z0, z1)
    s, c = np.linalg.norm(axis), float(z0 @ z1)
    turn = np.eye(3) if s < 1e-12 else matrix_from_rotvec(axis / s * np.arctan2(s, c))
    return turn @ R0


def tcp_for_target(calibration: HandEyeCalibration, target_mm, R_carm_transducer, T_flange_tcp=None) -> np.ndarray:
    """``T_base_tcp`` that puts the TCP (``T_flange_tcp``; default the estimated focal point
    ``T_flange_transducer``) on ``target_mm`` (C-arm frame) with the transducer orientation
    ``R_carm_transducer``."""
    X = calibration.T_flange_transducer
    T_ft = X if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    # The TCP's place in the transducer frame (the focal point, or the bias-corrected point).
    local = (invert_transform(X) @ T_ft)[:3, 3]
    R = np.asarray(R_carm_transducer, float)
    T_carm_transducer = make_transform(R, np.asarray(target_mm, float) - R @ local)
    return calibration.T_base_carm @ T_carm_transducer @ invert_transform(X) @ T_ft


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


def _start_joints(truth: GroundTruth) -> np.ndarray:
    """Where the operator jogged the robot: the flange pointing down, the designed focal point at
    ``truth.start_focal_base_mm`` (the joint solution closest to the home configuration)."""
    start_flange = make_transform(R_BASE_FLANGE_DOWN, truth.start_focal_base_mm
                                  - R_BASE_FLANGE_DOWN @ truth.T_flange_transducer_nominal[:3, 3])
    return inverse_kinematics_closest(start_flange, HOME_JOINTS_RAD)


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
    q = inverse_kinematics_closest(F_cmd, _start_joints(truth))
    return {"T_carm_base": truth.T_carm_base.copy(), "joints_rad": q, "T_base_flange": F_cmd,
            "T_carm_transducer": truth.T_carm_transducer(F_cmd), "T_carm_phantom": truth.T_carm_phantom.copy()}


def _treat(robot: Robot, truth: GroundTruth, calibration: HandEyeCalibration, config: TargetingStudyConfig,
           zone: TreatmentZone, R_des: np.ndarray, T_flange_tcp: np.ndarray, phantom: Volume, roi: np.ndarray,
           physical: TransducerModel, rng_cbct: np.random.Generator, journal: Path) -> tuple[ZoneSegmentation, Volume, dict]:
    """Position, treat ``zone``, simulate the post-treatment CBCT and segment it."""
    T_start = position_for_target(robot, calibration, zone.centre_mm, R_des, T_flange_tcp)
    plan = plan_treatment(zone, config.treatment_spacing_mm, int(config.pulses_per_point), axes=R_des,
                          inset_mm=config.treatment_inset_mm)
    # The plan's points are TCP targets: with the TCP at the (corrected) focal point, the point that
    # lands on each is the one the calibration treatment says the bubble cloud is at.
    run = execute_treatment(robot, plan, calibration.T_base_carm, T_start[:3, :3], journal,
                            T_flange_tcp=T_flange_tcp)
    T_base_flange = run.reached_T_base_tcp @ invert_transform(T_flange_tcp)
    T_true = truth.T_carm_base @ T_base_flange @ truth.T_flange_transducer
    seg, post = scan_treated_zone(phantom, roi, T_true, physical.focal_point_mm, truth.bubble_offset_mm,
                                  spec=PhantomSpec(), T_carm_phantom=truth.T_carm_phantom, rng=rng_cbct,
                                  blur_sigma_mm=config.cbct_blur_mm, noise_sd_hu=config.cbct_noise_hu,
                                  voxel_mm=config.cbct_voxel_mm)
    # The bubble clouds' true centroid (what a perfect segmentation would find).
    centres = T_true[:, :3, :3] @ (physical.focal_point_mm + truth.bubble_offset_mm) + T_true[:, :3, 3]
    info = {"n_points": len(plan), "T_base_tcp_start": T_start, "cloud_centroid_mm": centres.mean(axis=0),
            "T_carm_transducer_true_first": T_true[0]}
    return seg, post, info


def _phantom_for(truth: GroundTruth, config: TargetingStudyConfig) -> tuple[Volume, np.ndarray]:
    phantom = phantom_volume(PhantomSpec(), truth.T_carm_phantom, spacing_mm=config.phantom_voxel_mm)
    return phantom, phantom_mask(phantom, PhantomSpec(), truth.T_carm_phantom)


def _errors(prefix: str, seg: ZoneSegmentation, target: np.ndarray, R_des: np.ndarray, radius: float) -> dict:
    err = seg.centroid_mm - target
    axes = transducer_axes(make_transform(R_des))
    row = {f"{prefix}err_{d}": float(err @ axes[d]) for d in DIRECTIONS}
    row[f"{prefix}err_euclidean"] = float(np.linalg.norm(err))
    row[f"{prefix}radius_mm"] = float(seg.sphere_radius_mm)
    row[f"{prefix}radius_err_mm"] = float(seg.sphere_radius_mm - radius)
    row.update({f"{prefix}centroid_{a}": v for a, v in zip("xyz", seg.centroid_mm)})
    return row


def run_targeting_experiment(config: TargetingStudyConfig, seq: np.random.SeedSequence, *,
                             pose_model: TransducerModel, render_model: TransducerModel, physical: TransducerModel,
                             views: Sequence[View], robot_factory=None, keep_volumes: bool = False,
                             experiment: int = 0, segmenter=None, orientation=None) -> dict:
    """One experiment (module docstring) from the seed sequence ``seq``; returns one flat row.

    ``segmenter`` / ``orientation``: the calibration's pose-estimation stages (see
    :func:`calibrate_robot`; None: the oracles).

    ``robot_factory(seed, initial_joints_rad) -> context manager yielding a Robot`` (default
    :func:`sim_robot`); the robot starts where the operator jogged it, the flange pointing down
    with the designed focal point over the phantom.
    With ``keep_volumes`` the row also holds (under ``"_volumes"``) the pre/post-treatment CBCTs
    and the segmentation, for figures.
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
    phantom, roi = _phantom_for(truth, config)
    pre = simulate_cbct(phantom, rng_cbct, blur_sigma_mm=config.cbct_blur_mm, noise_sd_hu=config.cbct_noise_hu,
                        voxel_mm=config.cbct_voxel_mm)
    border = radius + 4.0  # the zone and half the segmentation window inside the phantom
    target = check_target(random_target(rng_target, PhantomSpec(), truth.T_carm_phantom, border_mm=border),
                          PhantomSpec(), truth.T_carm_phantom, volume=pre, margin_mm=radius)
    zone = TreatmentZone(target, diameter)
    row = {"experiment": experiment, "diameter_mm": diameter, **{f"target_{a}": v for a, v in zip("xyz", target)}}
    # The operator jogged the flange pointing down over the phantom: the robot starts there.
    q_start = _start_joints(truth)
    with robot_factory(robot_seed(s_robot), q_start) as robot, tempfile.TemporaryDirectory(prefix="histostudy-target-") as tmp:
        cal, cal_rows = calibrate_robot(robot, truth, config, pose_model=pose_model, render_model=render_model,
                                        physical=physical, views=views, rng_pose=np.random.default_rng(s_pose),
                                        rng_scene=np.random.default_rng(s_scene),
                                        rng_render=np.random.default_rng(s_render), rng_est=np.random.default_rng(s_est),
                                        segmenter=segmenter, orientation=orientation)
        R_des = target_orientation(cal)
        X = cal.T_flange_transducer
        # Calibration errors against the ground truth.
        row.update(cal_rms_focal_residual_mm=cal.rms_focal_residual_mm,
                   cal_max_rotation_residual_deg=cal.max_rotation_residual_deg,
                   cal_pose_error_mm=float(cal_rows["pose_error_mm"].mean()),
                   cal_X_rotation_deg=float(np.degrees(rotation_angle(X[:3, :3].T @ truth.T_flange_transducer[:3, :3]))),
                   cal_X_translation_mm=float(np.linalg.norm(X[:3, 3] - truth.T_flange_transducer[:3, 3])),
                   cal_Y_rotation_deg=float(np.degrees(rotation_angle(cal.T_carm_base[:3, :3].T @ truth.T_carm_base[:3, :3]))),
                   cal_Y_translation_mm=float(np.linalg.norm(cal.T_carm_base[:3, 3] - truth.T_carm_base[:3, 3])))
        F_cmd = tcp_for_target(cal, target, R_des) @ invert_transform(X)
        row["cal_error_at_target_mm"] = float(np.linalg.norm(truth.T_carm_transducer(F_cmd)[:3, 3] - target))

        bias_local = np.zeros(3)
        if config.bias_correction:
            # The calibration treatment: a test zone in a calibration phantom (same kind, drawn).
            rng_bias = np.random.default_rng(rng_target.integers(2**63))
            test_target = random_target(rng_bias, PhantomSpec(), truth.T_carm_phantom,
                                        border_mm=0.5 * config.bias_test_diameter_mm + 4.0)
            test_zone = TreatmentZone(test_target, config.bias_test_diameter_mm)
            seg_t, _, _ = _treat(robot, truth, cal, config, test_zone, R_des, X, phantom, roi, physical, rng_cbct,
                                 Path(tmp) / "calibration_treatment.json")
            bias_local = R_des.T @ (seg_t.centroid_mm - test_target)
        row.update({f"bias_learnt_{a}": v for a, v in zip(("lr", "tb", "depth"), (bias_local[0], bias_local[1], -bias_local[2]))})

        seg, post, info = _treat(robot, truth, cal, config, zone, R_des, X, phantom, roi, physical, rng_cbct,
                                 Path(tmp) / "treatment.json")
        row.update(_errors("", seg, target, R_des, radius))
        row["n_points"] = info["n_points"]
        row["cloud_err_euclidean"] = float(np.linalg.norm(info["cloud_centroid_mm"] - target))
        if config.bias_correction:
            X_corr = X @ make_transform(None, bias_local)
            seg_c, post_c, info_c = _treat(robot, truth, cal, config, zone, R_des, X_corr, phantom, roi, physical,
                                           rng_cbct, Path(tmp) / "treatment_corrected.json")
            row.update(_errors("corr_", seg_c, target, R_des, radius))
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
                        segmenter=None, orientation=None) -> pd.DataFrame:
    """Run ``config.n_experiments`` experiments; one row per (experiment, robot).

    ``segmenter`` / ``orientation``: the calibration's pose-estimation stages, e.g. the learned
    ones of :func:`histostudy.study.pose_estimation.study_stages` (None: the config's oracles).

    ``robot``: ``"sim"`` (:class:`SimulatedUR5e`), ``"rtde"`` (the simulated controller through
    ur_rtde) or ``"both"`` (each experiment on both, from the same seeds). Columns: experiment,
    robot, diameter_mm, target_*, the errors (``err_depth``, ``err_tb``, ``err_lr``,
    ``err_euclidean``, ``radius_err_mm``; ``corr_*`` with the bias correction), the learnt bias
    (``bias_learnt_*``, depth/TB/LR), the calibration's residuals and errors against the truth
    (``cal_*``), the moves made.
    """
    robots = {"sim": ("sim",), "rtde": ("rtde",), "both": ("sim", "rtde")}.get(robot)
    if robots is None:
        raise ValueError(f"robot must be 'sim', 'rtde' or 'both', got {robot!r}")
    factories = {"sim": sim_robot(config), "rtde": rtde_robot(config)}
    rows = []
    for e, seq in enumerate(np.random.SeedSequence(seed).spawn(config.n_experiments)):
        for name in robots:
            row = run_targeting_experiment(config, seq, pose_model=pose_model, render_model=render_model,
                                           physical=physical, views=views, robot_factory=factories[name],
                                           keep_volumes=keep_volumes, experiment=e, segmenter=segmenter,
                                           orientation=orientation)
            rows.append({"robot": name, **row})
            if progress:
                progress(f"experiment {e + 1}/{config.n_experiments} ({name}): {row['err_euclidean']:.2f} mm")
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------------------------
# Summaries
# ---------------------------------------------------------------------------------------------


def targeting_values(records: pd.DataFrame, prefix: str = "") -> dict:
    """The paper's targeting figures (mean, SD) keyed as :mod:`histostudy.reporting.paper`:
    ``targeting.euclidean``, ``targeting.mae.<d>``, ``targeting.bias.<d>``, ``targeting.radius_mae``;
    ``prefix="corr_"`` for the bias-corrected treatments."""
    if records.empty:
        raise ValueError("records is empty: no experiment to summarise")
    if f"{prefix}err_euclidean" not in records:
        raise ValueError(f"records has no {prefix}err_euclidean column (bias correction off?)")
    values = {"targeting.euclidean": _mean_sd(records[f"{prefix}err_euclidean"])}
    for d in DIRECTIONS:
        values[f"targeting.mae.{d}"] = _mean_sd(np.abs(records[f"{prefix}err_{d}"]))
        values[f"targeting.bias.{d}"] = _mean_sd(records[f"{prefix}err_{d}"])
    values["targeting.radius_mae"] = _mean_sd(np.abs(records[f"{prefix}radius_err_mm"]))
    return values


def summary(records: pd.DataFrame) -> pd.DataFrame:
    """Mean ± SD per robot of the targeting errors without and with bias correction, and of the
    calibration's errors against the ground truth (mm, deg)."""
    out = []
    fmt = lambda v: f"{v[0]:.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
    for robot, g in records.groupby("robot", sort=False):
        for prefix, label in (("", "uncorrected (paper)"), ("corr_", "bias-corrected")):
            if f"{prefix}err_euclidean" not in g:
                continue
            v = targeting_values(g, prefix)
            out.append({"robot": robot, "targeting": label, "experiments": len(g),
                        "euclidean": fmt(v["targeting.euclidean"]),
                        **{f"MAE {d}": fmt(v[f"targeting.mae.{d}"]) for d in DIRECTIONS},
                        **{f"bias {d}": f"{v[f'targeting.bias.{d}'][0]:+.2f}" for d in DIRECTIONS},
                        "radius MAE": fmt(v["targeting.radius_mae"])})
    return pd.DataFrame(out)


def plot_target_slices(volume: Volume, segmentation: ZoneSegmentation, target_mm, *, title: str = "",
                       half_width_mm: float = 30.0):
    """Fig. 7: transverse, frontal and sagittal slices of a post-treatment CBCT through the
    target, the target from the pre-treatment CBCT as a green dot and the segmented zone's outline
    in blue. Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    target = np.asarray(target_mm, dtype=np.float64).reshape(3)
    if not volume.contains(target)[0]:
        raise ValueError(f"target_mm={target.round(2).tolist()} lies outside the volume")
    i, j, k = np.round(volume.world_to_voxel(target)[0]).astype(int)
    x, y, z = volume.axes_mm()
    mask = segmentation.mask
    if mask.shape != volume.data.shape:
        raise ValueError(f"segmentation mask {mask.shape} does not match the volume {volume.data.shape}")
    # (name, image rows x cols, row axis, col axis, target (col, row), row/col labels)
    cuts = (("transverse (z = %.1f mm)" % z[k], volume.data[k], mask[k], y, x, (target[0], target[1]), "y (P) mm", "x (L) mm"),
            ("frontal (y = %.1f mm)" % y[j], volume.data[:, j, :], mask[:, j, :], z, x, (target[0], target[2]), "z (S) mm", "x (L) mm"),
            ("sagittal (x = %.1f mm)" % x[i], volume.data[:, :, i], mask[:, :, i], z, y, (target[1], target[2]), "z (S) mm", "y (P) mm"))
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    lo, hi = np.percentile(volume.data, [1, 99.5])
    for ax, (name, img, m, rows, cols, (tc, tr), rlab, clab) in zip(axes, cuts):
        extent = (cols[0], cols[-1], rows[0], rows[-1])
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi, origin="lower", extent=extent, interpolation="nearest")
        if m.any():
            ax.contour(cols, rows, m.astype(float), levels=[0.5], colors="tab:blue", linewidths=1.2)
        ax.plot(tc, tr, "o", color="lime", markersize=6, markeredgecolor="k")
        ax.set_xlim(tc - half_width_mm, tc + half_width_mm)
        # Transverse: anterior (-y, where the transducer is) at the top, as radiology shows it.
        flip = rlab.startswith("y")
        ax.set_ylim((tr + half_width_mm, tr - half_width_mm) if flip else (tr - half_width_mm, tr + half_width_mm))
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(clab)
        ax.set_ylabel(rlab)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
