"""Treating a zone (§II-D) and the bias-correcting calibration treatment (§II-A step 3, §IV): the
robot positioned and the plan executed, the bubble clouds at the physical transducer's true focal
points, the post-treatment CBCT simulated and segmented; ``b = R_des^T (centroid - target)`` (mm)
learnt from a test zone (docs/targeting-study.md, "Bias correction").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from histostudy.calibration import HandEyeCalibration
from histostudy.geometry import invert_transform
from histostudy.imaging import PhantomSpec, Volume, random_target
from histostudy.robot import Robot
from histostudy.transducer import TransducerModel
from histostudy.treatment import TreatmentZone, ZoneSegmentation, execute_treatment, plan_treatment, scan_treated_zone

from ..pose.reference import phantom_and_mask
from ._positioning import position_for_target
from .setup import GroundTruth, TargetingStudyConfig

__all__ = ["learn_bubble_bias", "phantom_for", "treat_zone"]


def treat_zone(robot: Robot, truth: GroundTruth, calibration: HandEyeCalibration, config: TargetingStudyConfig,
           zone: TreatmentZone, R_des: np.ndarray, T_flange_tcp: np.ndarray, phantom: Volume, roi: np.ndarray,
           physical: TransducerModel, rng_cbct: np.random.Generator, journal: Path) -> tuple[ZoneSegmentation, Volume,
                                                                                             dict]:
    """Position the TCP ``T_flange_tcp`` on ``zone``'s centre, treat the zone, simulate the
    post-treatment CBCT and segment it.

    Returns the segmentation, the post-treatment CBCT (HU) and an info dict: ``n_points`` (of the
    plan), ``T_base_tcp_start``, ``cloud_centroid_mm`` (the bubble clouds' true centroid, C-arm
    mm) and ``T_carm_transducer_true_first`` (the true transducer pose at the first point)."""
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


def phantom_for(truth: GroundTruth, config: TargetingStudyConfig) -> tuple[Volume, np.ndarray]:
    """The experiment's true layered phantom and the region the zone segmentation searches.

    Args:
        truth: the experiment's ground truth (``T_carm_phantom``).
        config: the study's parameters (``phantom_voxel_mm``).

    Returns:
        ``(phantom, mask)``: the phantom (HU on a ``config.phantom_voxel_mm`` grid, C-arm frame) and its
        boolean mask.
    """
    return phantom_and_mask(PhantomSpec(), truth.T_carm_phantom, config.phantom_voxel_mm)


def learn_bubble_bias(robot: Robot, truth: GroundTruth, calibration: HandEyeCalibration,
                      config: TargetingStudyConfig, R_des: np.ndarray, T_flange_transducer: np.ndarray,
                      phantom: Volume, roi: np.ndarray, physical: TransducerModel, rng_target: np.random.Generator,
                      rng_cbct: np.random.Generator, journal: Path) -> np.ndarray:
    """The calibration treatment: treat a test zone of ``config.bias_test_diameter_mm`` drawn in a
    calibration phantom (same kind as ``phantom``) and return its centroid's offset from the
    intended target in the transducer frame (mm, ``R_des^T (centroid - target)``).

    Draws the test target from a generator seeded by one draw of ``rng_target``; the
    post-treatment CBCT draws from ``rng_cbct``."""
    rng_bias = np.random.default_rng(rng_target.integers(2**63))
    test_target = random_target(rng_bias, PhantomSpec(), truth.T_carm_phantom,
                                border_mm=0.5 * config.bias_test_diameter_mm + 4.0)
    test_zone = TreatmentZone(test_target, config.bias_test_diameter_mm)
    seg_t, _, _ = treat_zone(robot, truth, calibration, config, test_zone, R_des, T_flange_transducer, phantom, roi,
                             physical, rng_cbct, journal)
    return R_des.T @ (seg_t.centroid_mm - test_target)
