"""The targeting study's set-up (§II-C, §II-D): its parameters (:class:`TargetingStudyConfig`) and
the ground truth one experiment draws (:func:`draw_ground_truth`: base, mount, phantom, start).
Transforms are 4x4 ``T_<to>_<from>`` in mm; the C-arm frame is LPS with its origin at the isocentre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from histostudy.calibration import R_BASE_FLANGE_DOWN
from histostudy.core import check_count
from histostudy.geometry import invert_transform, make_transform, matrix_from_rotvec, rotation_about_axis
from histostudy.imaging import FrameRenderConfig
from histostudy.learning import OracleSegmenter
from histostudy.robot import HOME_JOINTS_RAD, inverse_kinematics_closest
from histostudy.treatment import STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM

__all__ = ["GroundTruth", "TargetingError", "TargetingStudyConfig", "draw_ground_truth", "start_joints"]


class TargetingError(RuntimeError):
    """The targeting study cannot go on: a calibration pose's estimate failed its verdict, or the
    calibration poses do not determine the hand-eye calibration.
    """


@dataclass(frozen=True)
class TargetingStudyConfig(FrameRenderConfig):
    """Parameters of the targeting study (defaults: the standard profile's, the paper's set-up).

    The fluoroscopy rendering (``photons_per_pixel``, ``n_splats``, ``splat_sigma_mm``,
    ``background``, §II-B.2) is the shared :class:`~histostudy.imaging.FrameRenderConfig`, checks
    included; ``background`` is the scene behind the transducer at calibration (``"phantom"``: the
    water bath and phantom; ``"none"``: no scene, for fast tests).

    Args:
        photons_per_pixel: dose of the calibration frames, photons per unattenuated pixel.
        n_splats: splats per model point.
        splat_sigma_mm: splat SD (mm).
        background: the scene behind the transducer at calibration (``"none"``: no scene).
        n_experiments: phantom experiments (paper: 6).
        zone_diameters_mm: target sphere diameters drawn per experiment (paper: 20 or 25 mm).
        n_calibration_poses: robot poses of the hand-eye calibration (paper: 4; >= 3).
        calibration_acquisitions: biplane pairs acquired at most per calibration pose: a pair whose
            estimate fails its verdict is acquired again, as a lab would (>= 1; the paper does not say).
        calibration_tilt_deg: tilt of the tool axis from vertical at the calibration poses (each
            about a different horizontal axis).
        calibration_axial_deg: the transducer is also turned about its axis by up to this.
        calibration_offset_mm: focal points of the calibration poses within ± this of the start.
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
        bias_test_diameter_mm: diameter of the calibration treatment's test zone (mm, in (0, 30]).

    Raises:
        ValueError: a value out of its range, named with its value (an unknown degradation or mode
            included).
    """

    n_experiments: int = 6
    zone_diameters_mm: tuple = (20.0, 25.0)
    n_calibration_poses: int = 4
    calibration_acquisitions: int = 3
    calibration_tilt_deg: float = 15.0
    calibration_axial_deg: float = 30.0
    calibration_offset_mm: float = 15.0
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
        super().__post_init__()
        if isinstance(self.n_experiments,
                      bool) or int(self.n_experiments) != self.n_experiments or self.n_experiments < 1:
            raise ValueError(f"n_experiments must be an integer >= 1, got {self.n_experiments!r}")
        if int(self.n_calibration_poses) != self.n_calibration_poses or self.n_calibration_poses < 3:
            raise ValueError(f"n_calibration_poses must be an integer >= 3 (hand-eye needs 2 motions), "
                             f"got {self.n_calibration_poses!r}")
        check_count(self.calibration_acquisitions, "calibration_acquisitions")
        if not self.zone_diameters_mm or any(not (np.isfinite(d) and 0 < d <= 30) for d in self.zone_diameters_mm):
            raise ValueError(f"zone_diameters_mm must hold diameters in (0, 30] mm (the 50 mm phantom), "
                             f"got {self.zone_diameters_mm!r}")
        if not (np.isfinite(self.bias_test_diameter_mm) and 0 < self.bias_test_diameter_mm <= 30):
            raise ValueError(f"bias_test_diameter_mm must be in (0, 30] mm, got {self.bias_test_diameter_mm!r}")
        OracleSegmenter.named(self.degradation)  # a clear error now for an unknown name
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
            raise ValueError(f"bubble_offset_mm must be 3 numbers (transducer frame, mm), "
                             f"got {self.bubble_offset_mm!r}")

    def segmenter(self) -> OracleSegmenter:
        """The oracle segmenter of ``degradation``."""
        return OracleSegmenter.named(self.degradation)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """What the lab had but did not know (4x4 ``T_<to>_<from>``, mm).

    Args:
        T_carm_base: the robot base in the C-arm frame.
        T_flange_transducer: the transducer (digital frame: origin at the geometric focal point) on
            the flange, mounting error included.
        T_flange_transducer_nominal: the mount as designed (tool axis, no error), what the
            preprogrammed calibration poses are laid out with.
        T_carm_phantom: the layered phantom.
        start_focal_base_mm: where the operator jogged the focal point above the phantom before the
            calibration poses (3, base frame, mm).
        bubble_offset_mm: the bubble cloud's offset (3, transducer frame, mm).
    """

    T_carm_base: np.ndarray
    T_flange_transducer: np.ndarray
    T_flange_transducer_nominal: np.ndarray
    T_carm_phantom: np.ndarray
    start_focal_base_mm: np.ndarray
    bubble_offset_mm: np.ndarray

    def T_carm_transducer(self, T_base_flange) -> np.ndarray:
        """The true transducer pose for a (measured) flange pose.

        Args:
            T_base_flange: the flange pose (4x4, mm; flange -> base).

        Returns:
            ``T_carm_base @ T_base_flange @ T_flange_transducer`` (4x4, mm).
        """
        return self.T_carm_base @ np.asarray(T_base_flange, float) @ self.T_flange_transducer


def _random_small_rotation(rng: np.random.Generator, sd_deg: float) -> np.ndarray:
    return matrix_from_rotvec(rng.normal(0.0, np.radians(sd_deg), 3))


def draw_ground_truth(rng: np.random.Generator, config: TargetingStudyConfig) -> GroundTruth:
    """Draw the set-up of one experiment (see :class:`GroundTruth`).

    The base stands beside the table on the patient's right (world -x, LPS), its z axis up (world
    -y) within ``base_tilt_deg``, turned by up to ``base_yaw_deg``, at a horizontal distance in
    ``base_distance_mm`` from the isocentre and 150-250 mm below it; the transducer hangs from the
    flange with its +z along the flange's -z, the focal point ``flange_to_focal_mm`` away, plus the
    mounting error.

    Args:
        rng: the experiment's ground-truth stream (the draws' order fixes every seeded result).
        config: the study's parameters.

    Returns:
        The :class:`GroundTruth`.
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


def start_joints(truth: GroundTruth) -> np.ndarray:
    """Where the operator jogged the robot before the calibration: the flange pointing down, the
    designed focal point at ``truth.start_focal_base_mm``.

    Args:
        truth: the experiment's ground truth.

    Returns:
        The 6 joint angles (rad), the solution closest to the home configuration.

    Raises:
        UnreachablePoseError: no joint solution reaches the start pose.
    """
    start_flange = make_transform(R_BASE_FLANGE_DOWN, truth.start_focal_base_mm
                                  - R_BASE_FLANGE_DOWN @ truth.T_flange_transducer_nominal[:3, 3])
    return inverse_kinematics_closest(start_flange, HOME_JOINTS_RAD)
