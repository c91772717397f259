"""The targeting study's summaries (§III, §II-E.4): the paper's figures, the per-experiment tables
and the comparisons notebook 05 records, and the calibration-sensitivity table (beyond the paper).
Errors in mm (rotations in degrees) along the commanded depth/TB/LR axes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from histostudy.calibration import calibration_sensitivity

from ..pose.geometry import DIRECTIONS
from ..pose.metrics import mean_sd

__all__ = ["CALIBRATION_TABLE_CAPTION", "ERROR_TABLE_CAPTION", "SUMMARY_TABLE_CAPTION", "calibration_table",
           "error_table", "first_robot_rows", "robot_max_difference", "sensitivity_caption",
           "sensitivity_medians", "calibration_sensitivity_table", "summary", "targeting_comparisons",
           "targeting_values"]

ERROR_TABLE_CAPTION = ("Per experiment: target - zone centroid along depth/TB/LR and Euclidean, segmented radius - "
                       "planned radius (mm); corr_*: with the bias correction; bias_learnt_*: the calibration "
                       "treatment's offset")
CALIBRATION_TABLE_CAPTION = ("Calibration: mean pose-estimation error of the calibration poses, residuals, errors "
                             "against the truth (mm, deg)")
SUMMARY_TABLE_CAPTION = "Targeting (mm, mean ± SD over experiments) per robot, without and with the bias correction"

#: The calibration-sensitivity errors whose medians are tabulated (deg, mm).
SENSITIVITY_METRICS = ["X_rotation_error_deg", "X_translation_error_mm", "Y_rotation_error_deg",
                       "Y_translation_error_mm", "target_error_mm", "rms_focal_residual_mm"]


def targeting_values(records: pd.DataFrame, prefix: str = "") -> dict:
    """The paper's targeting figures (mean, SD) keyed as :mod:`histostudy.reporting.paper`:
    ``targeting.euclidean``, ``targeting.mae.<d>``, ``targeting.bias.<d>``, ``targeting.radius_mae``;
    ``prefix="corr_"`` for the bias-corrected treatments."""
    if records.empty:
        raise ValueError("records is empty: no experiment to summarise")
    if f"{prefix}err_euclidean" not in records:
        raise ValueError(f"records has no {prefix}err_euclidean column (bias correction off?)")
    values = {"targeting.euclidean": mean_sd(records[f"{prefix}err_euclidean"])}
    for d in DIRECTIONS:
        values[f"targeting.mae.{d}"] = mean_sd(np.abs(records[f"{prefix}err_{d}"]))
        values[f"targeting.bias.{d}"] = mean_sd(records[f"{prefix}err_{d}"])
    values["targeting.radius_mae"] = mean_sd(np.abs(records[f"{prefix}radius_err_mm"]))
    return values


def summary(records: pd.DataFrame) -> pd.DataFrame:
    """Mean ± SD per robot of the targeting errors without and with bias correction, and of the
    calibration's errors against the ground truth (mm, deg)."""
    out = []
    def fmt(v):
        return f"{v[0]:.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
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


def first_robot_rows(records: pd.DataFrame) -> pd.DataFrame:
    """The rows of the first robot in ``records`` (one per experiment), renumbered from 0: the
    paper's figures count each experiment once however many robots ran it."""
    return records[records["robot"] == records["robot"].iloc[0]].reset_index(drop=True)


def _has_correction(records: pd.DataFrame) -> bool:
    return "corr_err_euclidean" in records


def error_table(records: pd.DataFrame) -> pd.DataFrame:
    """Per (experiment, robot): the targeting errors (mm), with the bias correction's errors and the
    learnt bias where the study ran it, and the treatment's points and the robot's moves."""
    columns = ["experiment", "robot", "diameter_mm", "err_depth", "err_tb", "err_lr", "err_euclidean",
               "radius_err_mm"]
    if _has_correction(records):
        columns += ["corr_err_depth", "corr_err_tb", "corr_err_lr", "corr_err_euclidean", "corr_radius_err_mm",
                    "bias_learnt_depth", "bias_learnt_tb", "bias_learnt_lr"]
    return records[columns + ["n_points", "moves"]]


def calibration_table(records: pd.DataFrame) -> pd.DataFrame:
    """Per (experiment, robot): the calibration's residuals beside its errors against the ground
    truth (mm, deg) and the physical transducer's focal-point offset (mm)."""
    return records[["experiment", "robot", "cal_pose_error_mm", "cal_rms_focal_residual_mm",
                    "cal_max_rotation_residual_deg", "cal_X_rotation_deg", "cal_X_translation_mm",
                    "cal_Y_rotation_deg", "cal_Y_translation_mm", "cal_error_at_target_mm",
                    "physical_focal_offset_mm"]]


def robot_max_difference(records: pd.DataFrame) -> float | None:
    """The largest absolute difference, over every float column of every experiment, between the
    ``"sim"`` and ``"rtde"`` rows of the same experiment; None unless both robots ran."""
    if set(records["robot"]) != {"sim", "rtde"}:
        return None
    numeric = [c for c in records.columns if records[c].dtype.kind == "f"]
    sim = records[records["robot"] == "sim"].set_index("experiment")[numeric]
    rtde = records[records["robot"] == "rtde"].set_index("experiment")[numeric]
    return float(np.nanmax(np.abs(sim.to_numpy() - rtde.to_numpy())))


def targeting_comparisons(records: pd.DataFrame) -> list[dict]:
    """The comparisons with the paper notebook 05 records, in order, each the keyword arguments of
    :meth:`histostudy.reporting.SectionWriter.compare`: the calibration against the truth, §III's
    targeting figures over the first robot's experiments, the bias-corrected figures (when the
    study ran the correction) and the two robots' agreement (when both ran)."""
    main = first_robot_rows(records)
    out: list[dict] = [
        dict(key="targeting.calibration_error_at_target",
             label="Calibration error at the target (true focal point of the commanded pose)",
             ours=mean_sd(main["cal_error_at_target_mm"]), unit="mm", paper_key="",
             note="the simulation's ground truth; the lab cannot measure it"),
        dict(key="targeting.calibration_rotation", label="Calibration X (transducer on flange) rotation error",
             ours=mean_sd(main["cal_X_rotation_deg"]), unit="°", paper_key="")]
    values = targeting_values(main)
    out.append(dict(key="targeting.euclidean", label="Targeting error, Euclidean", ours=values["targeting.euclidean"],
                    unit="mm"))
    out += [dict(key=f"targeting.mae.{d}", label=f"Targeting MAE, {d}", ours=values[f"targeting.mae.{d}"], unit="mm")
            for d in DIRECTIONS]
    out += [dict(key=f"targeting.bias.{d}", label=f"Targeting bias, {d}", ours=values[f"targeting.bias.{d}"][0],
                 unit="mm") for d in DIRECTIONS]
    out.append(dict(key="targeting.radius_mae", label="Radius MAE (segmented vs planned)",
                    ours=values["targeting.radius_mae"], unit="mm"))
    out.append(dict(key="targeting.n_studies", label="Targeting experiments", ours=int(len(main))))
    if _has_correction(main):
        corrected = targeting_values(main, "corr_")
        out.append(dict(key="targeting.corrected.euclidean", label="Targeting error with bias correction, Euclidean",
                        ours=corrected["targeting.euclidean"], unit="mm", paper_key="targeting.euclidean",
                        note="beyond the paper: calibration treatment (§IV)"))
        out += [dict(key=f"targeting.corrected.bias.{d}", label=f"Targeting bias with bias correction, {d}",
                     ours=corrected[f"targeting.bias.{d}"][0], unit="mm", paper_key=f"targeting.bias.{d}",
                     note="beyond the paper") for d in DIRECTIONS]
    max_difference = robot_max_difference(records)
    if max_difference is not None:
        out.append(dict(key="targeting.rtde_vs_sim",
                        label="Largest difference, SimulatedUR5e vs RTDERobot + controller, same seed",
                        ours=max_difference, unit="mm", digits=9, paper_key="",
                        note="every numeric column of every experiment"))
    return out


def sensitivity_medians(sensitivity: pd.DataFrame) -> pd.DataFrame:
    """Median of each :data:`SENSITIVITY_METRICS` column per condition (every other column but
    ``trial``: the number of poses and the pose noise)."""
    group = [c for c in sensitivity.columns if c not in SENSITIVITY_METRICS and c != "trial"]
    return sensitivity.groupby(group)[SENSITIVITY_METRICS].median().reset_index()


def calibration_sensitivity_table(n_poses, pose_noise, n_trials: int, seed: np.random.SeedSequence) -> pd.DataFrame:
    """Beyond the paper: the median hand-eye calibration errors of a Monte-Carlo
    (:func:`histostudy.calibration.calibration_sensitivity`) per number of robot poses
    ``n_poses`` and pose-estimation noise ``pose_noise`` (pairs of translation SD mm, rotation SD
    deg), ``n_trials`` trials each."""
    sensitivity = calibration_sensitivity(tuple(n_poses), tuple(map(tuple, pose_noise)), n_trials=n_trials,
                                          rng=np.random.default_rng(seed))
    return sensitivity_medians(sensitivity)


def sensitivity_caption(n_trials: int) -> str:
    """The caption of :func:`calibration_sensitivity_table`'s table."""
    return (f"Median calibration errors over {n_trials} trials per number of poses and pose noise (X = transducer "
            "on flange, Y = robot base in the C-arm; target = focal-point error at the isocentre)")
