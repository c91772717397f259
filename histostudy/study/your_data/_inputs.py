"""Notebook 06's inputs and their tables: the lab's files (or the lab-like dataset), the transducer
from CAD meshes, the station poses, the hand-eye calibration, the tracked cine and the planned move.
Lengths in mm, 4x4 ``T_<to>_<from>`` (docs/architecture.md, "Frames and units").
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.calibration import HandEyeCalibration
from histostudy.imaging import Volume, load_views
from histostudy.lab import TargetingPlan, accepted_stations, calibrate_from_poses, load_flange_poses, plan_targeting
from histostudy.pose import Tracker, frames_from_files, pose_from_files, pose_record
from histostudy.transducer import TransducerModel

from ..targeting import plot_target_slices
from ..targeting.setup import TargetingStudyConfig
from .lab_dataset import write_lab_dataset

_FRAME_SUFFIXES = (".dcm", ".dicom", ".npy", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class LabInputs:
    """The lab's files (paths; None where not given) and, for the generated dataset, its truth.

    Args:
        views: the views file (``views.json``); None: the frames' DICOM geometry tags.
        stations: one folder per calibration station (its biplane pair).
        flange_poses: the flange poses the robot reported at the stations.
        cine: the cine's files, one per plane.
        cbct: the CBCT (NIfTI file or DICOM folder).
        transducer_meshes: the folder of the transducer's meshes; None: the paper's digital model.
        target_mm: the target (x, y, z), C-arm frame, mm.
        truth: the generated dataset's synthetic truth (``truth.json``); None for a lab's own files.
        generated: whether the files are the generated lab-like dataset.
    """

    views: Path | None
    stations: tuple
    flange_poses: Path
    cine: tuple
    cbct: Path
    transducer_meshes: Path | None
    target_mm: np.ndarray
    truth: dict | None
    generated: bool


def lab_inputs(data_dir: str | os.PathLike | None, *, output_dir: str | os.PathLike, seed: int,
               target_mm=None, n_cine_frames: int = 4, render: dict | None = None) -> LabInputs:
    """The inputs of notebook 06: those in ``data_dir`` (laid out as the lab-like dataset:
    ``views.json``, ``calibration/station_*/``, ``calibration/flange_poses.json``, ``cine/*.dcm``,
    ``cbct.nii.gz`` or ``cbct/``, ``transducer/``), or, with ``data_dir`` None, the lab-like dataset
    generated into ``output_dir/lab_data`` from ``seed``. ``target_mm``: the target (C-arm mm);
    default the dataset's suggested one. ``render``: the generated frames' dose and splatting
    (:class:`~histostudy.imaging.FrameRenderConfig` fields; default the study's)."""
    if data_dir is None:
        config = TargetingStudyConfig(n_experiments=1, background="phantom", **(render or {}))
        ds = write_lab_dataset(Path(output_dir) / "lab_data", seed=seed, n_cine_frames=n_cine_frames, config=config)
        data_dir = ds.folder
    folder = Path(data_dir)
    if not folder.is_dir():
        raise FileNotFoundError(f"data_dir {str(folder)!r}: no such folder")
    manifest = json.loads((folder / "dataset.json").read_text()) if (folder / "dataset.json").is_file() else {}
    stations = tuple(sorted(p for p in (folder / "calibration").glob("station_*") if p.is_dir()))
    cine = tuple(sorted((folder / "cine").glob("*.dcm")))
    cbct = next((p for p in (folder / "cbct.nii.gz", folder / "cbct.nii", folder / "cbct") if p.exists()), None)
    missing = [name for name, v in (("calibration/station_*", stations), ("cine/*.dcm", cine), ("cbct", cbct)) if not v]
    if missing:
        raise FileNotFoundError(f"data_dir {str(folder)!r} lacks {missing} "
                                f"(see histostudy.study.your_data.lab_dataset)")
    assert cbct is not None
    if target_mm is None:
        if "suggested_target_mm" not in manifest:
            raise ValueError("target_mm must be given (x, y, z in the CBCT's world frame, mm): the data has no "
                             "suggested target")
        target_mm = manifest["suggested_target_mm"]
    truth = json.loads((folder / "truth.json").read_text()) if (folder / "truth.json").is_file() else None
    meshes = folder / "transducer"
    return LabInputs(views=folder / "views.json" if (folder / "views.json").is_file() else None,
                     stations=stations, flange_poses=folder / "calibration" / "flange_poses.json", cine=cine,
                     cbct=cbct, transducer_meshes=meshes if meshes.is_dir() else None,
                     target_mm=np.asarray(target_mm, dtype=np.float64), truth=truth,
                     generated=bool(manifest))


def transducer_model(inputs: LabInputs, spacing_mm: float = 0.47) -> TransducerModel:
    """The transducer the pose is estimated with: from the lab's CAD meshes (one file per feature
    class, named after it) when there are any, else the paper's digital model."""
    if inputs.transducer_meshes is None:
        return TransducerModel.build(spacing_mm=spacing_mm)
    files = {p.stem: p for p in sorted(inputs.transducer_meshes.iterdir()) if p.suffix.lower() in (".stl", ".ply",
                                                                                                   ".obj", ".vtp")}
    return TransducerModel.from_meshes(files, spacing_mm=spacing_mm)


def _station_frames(station: Path) -> list[Path]:
    return sorted(p for p in station.iterdir() if p.suffix.lower() in _FRAME_SUFFIXES)


def _focal_error_mm(T_est, T_true) -> float:
    return float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_true)[:3, 3]))


def station_poses(inputs: LabInputs, model: TransducerModel, seed: int) -> tuple[list[dict], pd.DataFrame]:
    """The pose record of each calibration station (:func:`histostudy.pose.pose_record`) and a
    table: focal point, verdict, seconds and, with a truth, the focal error."""
    records, rows = [], []
    for k, station in enumerate(inputs.stations):
        frames = _station_frames(station)
        result = pose_from_files(frames, inputs.views, model=model, seed=seed + k)
        record = pose_record(result, frames, model=model)
        records.append(record)
        row = {"station": station.name, **{f"focal_{a}_mm": v for a, v in zip("xyz", record["focal_point_mm"])},
               "accepted": record["accepted"], "seconds": result.timings_s.get("total", np.nan)}
        if inputs.truth is not None:
            row["focal_error_mm"] = _focal_error_mm(result.T_carm_transducer,
                                                    inputs.truth["station_T_carm_transducer"][k])
        rows.append(row)
    return records, pd.DataFrame(rows)


def calibration_table(records: list[dict], inputs: LabInputs) -> tuple[HandEyeCalibration, pd.DataFrame]:
    """The checked hand-eye calibration of the stations whose pose the verdict accepted
    (:func:`histostudy.lab.calibrate_from_poses`, refused stations left out while 3 remain) and
    its residuals per station used, with the error of ``T_carm_base`` at the target against a truth."""
    calibration = calibrate_from_poses(records, load_flange_poses(inputs.flange_poses), on_refused="exclude")
    used = accepted_stations(records)
    table = pd.DataFrame({"station": [inputs.stations[i].name for i in used],
                          "focal_residual_mm": calibration.focal_residuals_mm,
                          "rotation_residual_deg": calibration.rotation_residuals_deg})
    if inputs.truth is not None:
        # Where the calibrated chain and the true one put a flange-carried point at the target.
        T_true = np.asarray(inputs.truth["T_carm_base"]) @ np.linalg.inv(calibration.T_carm_base)
        table["target_error_of_T_carm_base_mm"] = float(np.linalg.norm(T_true[:3, :3] @ inputs.target_mm
                                                                       + T_true[:3, 3] - inputs.target_mm))
    return calibration, table


def cine_frame_count(inputs: LabInputs) -> int:
    """Frames in the cine (the smallest count over the planes)."""
    import pydicom

    return min(int(getattr(pydicom.dcmread(p, stop_before_pixels=True), "NumberOfFrames", 1)) for p in inputs.cine)


def track_cine(inputs: LabInputs, model: TransducerModel, seed: int,
               max_frames: int | None = None) -> tuple[list, pd.DataFrame]:
    """The pose tracked over the cine's biplane frames (:class:`histostudy.pose.Tracker`: from
    scratch on the first pair, warm-started after) and a table per frame: focal point, verdict,
    seconds, re-acquisitions and, with a truth, the focal error."""
    n = cine_frame_count(inputs) if max_frames is None else min(max_frames, cine_frame_count(inputs))
    views = load_views(inputs.views) if inputs.views is not None else None
    first = frames_from_files(inputs.cine, inputs.views, frame_index=0)
    # the full-frame path (fast=False): the study's numbers, as estimate_pose gives them
    tracker = Tracker(model, views or [f.view for f in first], rng=np.random.default_rng(seed),
                      fast=False, raise_on_failure=False)
    results, rows = [], []
    for k in range(n):
        frames = first if k == 0 else frames_from_files(inputs.cine, inputs.views, frame_index=k)
        result = tracker.update(frames)
        results.append(result)
        row = {"frame": k, **{f"focal_{a}_mm": v for a, v in zip("xyz", result.focal_point_mm)},
               "accepted": bool(result.verdict.ok), "seconds": result.timings_s.get("total", np.nan),
               "reacquired_so_far": tracker.n_reacquired}
        if inputs.truth is not None:
            row["focal_error_mm"] = _focal_error_mm(result.T_carm_transducer,
                                                    inputs.truth["cine_T_carm_transducer"][k])
        rows.append(row)
    return results, pd.DataFrame(rows)


def plan_table(plan: TargetingPlan) -> pd.DataFrame:
    """The planned move as a table.

    Args:
        plan: the plan (:func:`drive_robot`'s).

    Returns:
        Rows ``quantity``, ``value``: the target (C-arm, mm), the commanded TCP position (robot base,
        mm), the joints at the start and at the target (deg) and the largest joint move (deg).
    """
    rows = [{"quantity": "target (C-arm, mm)", "value": np.round(plan.target_mm, 2).tolist()},
            {"quantity": "TCP position (robot base, mm)", "value": np.round(plan.T_base_tcp[:3, 3], 2).tolist()},
            {"quantity": "joints at the start (deg)", "value": np.round(np.degrees(plan.start_joints_rad), 1).tolist()},
            {"quantity": "joints at the target (deg)", "value": np.round(np.degrees(plan.joints_rad), 1).tolist()},
            {"quantity": "largest joint move (deg)", "value": round(float(np.degrees(plan.joint_travel_rad)), 2)}]
    return pd.DataFrame(rows)


def plot_cbct_target(volume: Volume, target_mm, *, half_width_mm: float = 40.0, title: str = ""):
    """Transverse, frontal and sagittal CBCT slices through ``target_mm`` (C-arm mm), the target
    as a green dot (:func:`histostudy.study.targeting.plot_target_slices` without a treated zone)."""
    return plot_target_slices(volume, None, target_mm, title=title, half_width_mm=half_width_mm)


def target_plan(calibration: HandEyeCalibration, inputs: LabInputs, volume: Volume,
                start_joints_rad=None) -> TargetingPlan:
    """:func:`histostudy.lab.plan_targeting` for the inputs' target in ``volume``, from
    ``start_joints_rad`` (the robot's joints; default: the generated dataset's start, else home)."""
    if start_joints_rad is None and inputs.truth is not None:
        start_joints_rad = inputs.truth["cine_start_joints_rad"]
    return plan_targeting(calibration, inputs.target_mm, volume=volume, start_joints_rad=start_joints_rad)


def accepted_focal_errors(stations: pd.DataFrame, cine: pd.DataFrame) -> tuple[float, float] | None:
    """Mean and SD of the focal error over the accepted poses of the stations and the cine.

    Args:
        stations: the ``table`` of :func:`stations_section` (columns ``accepted`` and, with a truth,
            ``focal_error_mm``).
        cine: the ``table`` of :func:`tracking_section`.

    Returns:
        ``(mean, sd)`` in mm (sd 0 for one pose); None without a truth (a lab's own data) or without
        an accepted pose.
    """
    errors = [t.loc[t["accepted"], "focal_error_mm"] for t in (stations, cine) if "focal_error_mm" in t]
    values = pd.concat(errors).to_numpy(float) if errors else np.zeros(0)
    if len(values) == 0:
        return None
    return float(values.mean()), float(values.std(ddof=1)) if len(values) > 1 else 0.0
