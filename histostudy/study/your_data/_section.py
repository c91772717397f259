"""Notebook 06's section: its set-up (:func:`prepare`), one part per heading, and
:func:`drive_robot`, the one call that plans the move and makes it only when asked (the dry-run guard).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.calibration import HandEyeCalibration
from histostudy.core import check_positive
from histostudy.imaging import Volume
from histostudy.lab import TargetingPlan, execute_targeting
from histostudy.pose import frames_from_files
from histostudy.robot import Robot
from histostudy.transducer import TransducerModel

from ..section import SectionPart, Timer
from ..section import timer_or_untimed as _timer
from ..targeting.setup import TargetingStudyConfig
from ._inputs import (
    LabInputs,
    _station_frames,
    calibration_table,
    lab_inputs,
    plan_table,
    plot_cbct_target,
    station_poses,
    target_plan,
    track_cine,
    transducer_model,
)
from ._parameters import YourDataConfig, _check_bool
from .moving_cine import write_moving_cine
from .moving_cine_live import MovingCineRun, count_table, frame_table, plot_focal_error, stream_moving_cine

# --- The notebook's section: its set-up, then one part per heading ---------------------------------


@dataclass(frozen=True)
class YourDataSetup:
    """What notebook 06 runs on (made by :func:`prepare`).

    Args:
        params: the checked parameters.
        inputs: the lab's files, or the generated dataset's with its truth.
        model: the transducer model the poses are estimated with (from the lab's meshes, or the
            paper's digital model), at ``params.pose_spacing_mm``.
        seed: the study seed.
        output_dir: the section's report folder (the generated dataset, cines and pose files go there).
    """

    params: YourDataConfig
    inputs: LabInputs
    model: TransducerModel
    seed: int
    output_dir: Path


def prepare(params: YourDataConfig | Mapping, seed: int, output_dir: str | os.PathLike, *,
            timer: Timer | None = None) -> YourDataSetup:
    """The section's set-up: the lab's files in ``params.data_dir`` (or the lab-like dataset generated
    into ``output_dir/lab_data`` from ``seed``) and the transducer model.

    Args:
        params: a :class:`YourDataConfig`, or a mapping naming its fields (checked into one).
        seed: the study seed (the generated dataset's draws derive from it).
        output_dir: the section's report folder.
        timer: ``timer(name)`` -> a context manager timing the set-up under ``"inputs"`` (e.g.
            ``SectionWriter.timer``); None: untimed.

    Returns:
        The :class:`YourDataSetup`.

    Raises:
        ValueError: a bad or missing parameter, or no target (``target_mm`` None and the data
            suggests none).
        FileNotFoundError: ``data_dir`` is not a folder or lacks the stations, the cine or the CBCT.
    """
    config = params if isinstance(params, YourDataConfig) else YourDataConfig.from_parameters(params)
    with _timer(timer)("inputs"):
        inputs = lab_inputs(config.data_dir, output_dir=output_dir, seed=seed, target_mm=config.target_mm,
                            n_cine_frames=config.n_cine_frames, render=config.render())
        model = transducer_model(inputs, config.pose_spacing_mm)
    return YourDataSetup(config, inputs, model, seed, Path(output_dir))


def inputs_part(setup: YourDataSetup) -> SectionPart:
    """What the section runs on.

    Args:
        setup: the section's set-up.

    Returns:
        A part with values ``generated_dataset`` (whether the lab-like dataset was generated) and
        ``model_points`` (the model's points per feature class).
    """
    return SectionPart(values={"generated_dataset": setup.inputs.generated,
                               "model_points": {feature.name: n for feature, n in setup.model.n_points.items()}})


@dataclass(frozen=True, eq=False)
class StationsSection:
    """The pose at each calibration station (:func:`stations_section`).

    Args:
        records: one pose record per station (:func:`histostudy.pose.pose_record`).
        table: one row per station: focal point (mm, C-arm frame), verdict, seconds and, with a
            truth, the focal error (mm).
        part: the report's part (table ``station_poses``).
    """

    records: list
    table: pd.DataFrame
    part: SectionPart


def stations_section(setup: YourDataSetup, *, timer: Timer | None = None) -> StationsSection:
    """The pose at each calibration station, from its biplane pair through the shipped learned stages.

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager timing the whole (``"station poses"``); None: untimed.

    Returns:
        The :class:`StationsSection`.
    """
    with _timer(timer)("station poses"):
        records, table = station_poses(setup.inputs, setup.model, setup.seed)
    return StationsSection(records, table, SectionPart(tables={"station_poses": (
        table, "The pose estimate at each calibration station (C-arm frame, mm).")}))


def station_overlay(setup: YourDataSetup, stations: StationsSection, station: int = 0) -> dict:
    """The arguments of :func:`histostudy.reporting.plot_pose_overlay` for one calibration station.

    Args:
        setup: the section's set-up.
        stations: :func:`stations_section`'s result.
        station: the station's index.

    Returns:
        ``frames`` (as the pose was estimated from), ``model``, ``T_carm_transducer`` (the estimate,
        4x4, maps transducer -> C-arm, mm) and ``rng`` (a Generator seeded with the section's seed).

    Raises:
        IndexError: no such station.
    """
    frames = frames_from_files(_station_frames(setup.inputs.stations[station]), setup.inputs.views)
    return dict(frames=frames, model=setup.model, T_carm_transducer=stations.records[station]["T_carm_transducer"],
                rng=np.random.default_rng(setup.seed))


#: The caption of the station overlay figure (``station_0_overlay``).
STATION_OVERLAY_CAPTION = "Station 0: the frames and the model in the estimated pose."


@dataclass(frozen=True, eq=False)
class CalibrationSection:
    """The hand-eye calibration (:func:`calibration_section`).

    Args:
        calibration: the checked calibration.
        table: its residuals per station used (focal, mm; rotation, deg) and, with a truth, the error
            of ``T_carm_base`` at the target (mm).
        part: the report's part.
    """

    calibration: HandEyeCalibration
    table: pd.DataFrame
    part: SectionPart


def calibration_section(setup: YourDataSetup, stations: StationsSection) -> CalibrationSection:
    """The hand-eye calibration (§II-C) of the stations whose pose the verdict accepted (refused
    stations left out while 3 remain).

    Args:
        setup: the section's set-up.
        stations: :func:`stations_section`'s result.

    Returns:
        The :class:`CalibrationSection`; its part: table ``calibration`` and value
        ``calibration_max_focal_residual_mm``.

    Raises:
        ValueError: fewer than 3 accepted stations, or a calibration beyond its residual bounds
            (from :func:`histostudy.lab.calibrate_from_poses`).
    """
    calibration, table = calibration_table(stations.records, setup.inputs)
    return CalibrationSection(calibration, table, SectionPart(
        tables={"calibration": (table, "Residuals of the hand-eye calibration per station.")},
        values={"calibration_max_focal_residual_mm": calibration.max_focal_residual_mm}))


@dataclass(frozen=True, eq=False)
class TrackingSection:
    """The pose tracked over the cine (:func:`tracking_section`).

    Args:
        results: the tracker's result per frame pair.
        table: one row per frame: focal point (mm, C-arm frame), verdict, seconds, re-acquisitions
            and, with a truth, the focal error (mm).
        part: the report's part (with a truth, the focal errors and their figure).
    """

    results: list
    table: pd.DataFrame
    part: SectionPart


def plot_cine_focal_error(cine: pd.DataFrame):
    """The tracked focal error against the truth per cine frame (:func:`track_cine`'s table, with a
    truth); a pyplot figure."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6, 3))
    plt.plot(cine["frame"], cine["focal_error_mm"], "o-")
    plt.xlabel("cine frame")
    plt.ylabel("focal error (mm)")
    plt.title("Tracked focal error against the truth")
    return fig


def tracking_section(setup: YourDataSetup, *, timer: Timer | None = None) -> TrackingSection:
    """The pose tracked over the cine's pairs (:class:`histostudy.pose.Tracker`: from scratch on the
    first, warm-started after), at most ``params.max_tracked_frames`` of them.

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager timing the whole (``"tracking"``); None: untimed.

    Returns:
        The :class:`TrackingSection`.
    """
    with _timer(timer)("tracking"):
        results, table = track_cine(setup.inputs, setup.model, setup.seed, setup.params.max_tracked_frames)
    part = SectionPart(tables={"cine_poses": (table, "The tracked pose per cine frame (C-arm frame, mm).")})
    if "focal_error_mm" in table:
        part = SectionPart(tables=part.tables, values={"cine_focal_error_mm": table["focal_error_mm"].tolist()},
                           figures={"cine_focal_error": (plot_cine_focal_error(table),
                                                         "Focal error of the tracked pose per cine frame.")})
    return TrackingSection(results, table, part)


@dataclass(frozen=True, eq=False)
class MovingCineSection:
    """The moving cine streamed through the receiver (:func:`moving_cine_section`).

    Args:
        run: the stream (:func:`histostudy.study.your_data.moving_cine_live.stream_moving_cine`).
        frames: one row per cine frame (posed, dropped or refused; focal error, mm; latency, s).
        counts: the run in numbers.
        part: the report's part (the tables, the figure, the receiver's stats and, with 2 or more
            accepted poses, the comparison with Table II).
    """

    run: MovingCineRun
    frames: pd.DataFrame
    counts: pd.DataFrame
    part: SectionPart


def moving_cine_section(setup: YourDataSetup, *, timer: Timer | None = None) -> MovingCineSection:
    """A cine of the robot touring the margin points, generated and streamed at its frame rate
    through the receiver on loopback (beyond the paper).

    The cine (``moving_cine_s`` at ``moving_cine_fps``, the robot at up to ``moving_cine_speed_mm_s``,
    rendered as the generated frames are) is written into ``output_dir/moving_cine``; at most
    ``max_queued_pairs`` wait for a pose; the poses go to ``output_dir/moving_cine_poses.jsonl``.

    Args:
        setup: the section's set-up (its parameters say the cine).
        timer: ``timer(name)`` -> a context manager timing ``"moving cine: rendering"`` and
            ``"moving cine: streamed"``; None: untimed.

    Returns:
        The :class:`MovingCineSection`.

    Raises:
        ConnectionError: the sender could not reach the receiver.
    """
    p, timer = setup.params, _timer(timer)
    render = TargetingStudyConfig(n_experiments=1, background="phantom", **p.render())
    with timer("moving cine: rendering"):
        cine = write_moving_cine(setup.output_dir / "moving_cine", seed=setup.seed, duration_s=p.moving_cine_s,
                                 fps=p.moving_cine_fps, max_speed_mm_s=p.moving_cine_speed_mm_s, config=render)
    with timer("moving cine: streamed"):
        run = stream_moving_cine(cine, setup.model, setup.seed, max_queued_pairs=p.max_queued_pairs,
                                 output_path=setup.output_dir / "moving_cine_poses.jsonl")
    frames = frame_table(run, cine)
    counts = count_table(run, frames)
    accepted = frames.loc[frames["accepted"], "focal_error_mm"]
    comparisons = () if len(accepted) <= 1 else (dict(
        key="lab.moving_cine_focal_error", label=f"focal error while the robot moves, {p.moving_cine_fps:g} "
        "frames/s streamed through the receiver", ours=(float(accepted.mean()), float(accepted.std())),
        unit="mm", paper_key="table2.center_mae.overall",
        note="beyond the paper: its poses were of a transducer at rest; here the accepted poses of the pairs "
             "the fast tracker kept up with"),)
    part = SectionPart(
        tables={"moving_cine_frames": (frames, "Each frame of the moving cine: posed, dropped or refused; how it "
                                       "was tracked; focal error against the truth (mm); latency (s)."),
                "moving_cine_counts": (counts, "The moving cine through the receiver: counts, rates, latency (s) "
                                       "and focal error of the accepted poses (mm).")},
        figures={"moving_cine_focal_error": (plot_focal_error(frames), f"Focal error per frame of a "
                                             f"{p.moving_cine_s:g} s cine at {p.moving_cine_fps:g} frames/s streamed "
                                             "through the receiver; ticks: frames dropped; rings: estimates from "
                                             "scratch.")},
        values={"moving_cine_stats": run.stats}, comparisons=comparisons)
    return MovingCineSection(run, frames, counts, part)


def focal_error_part(errors: tuple[float, float] | None) -> SectionPart:
    """The accepted poses' focal error beside Table II's overall centre error.

    Args:
        errors: ``(mean, sd)`` in mm (:func:`accepted_focal_errors`), or None (no truth).

    Returns:
        A part with the comparison; an empty part for None.
    """
    if errors is None:
        return SectionPart()
    return SectionPart(comparisons=(dict(
        key="lab.focal_error", label="focal error on the lab-like DICOM files (stations and cine)", ours=errors,
        unit="mm", paper_key="table2.center_mae.overall",
        note="the whole lab path: DICOM XA tags, mesh model, learned stages, tracking"),))


def drive_robot(calibration: HandEyeCalibration, inputs: LabInputs, volume: Volume, *,
                robot: str | Robot | None = None, dry_run: bool = True,
                speed_mm_s: float = 50.0) -> tuple[TargetingPlan, dict | None]:
    """Plan the move of the calibrated focal point onto the inputs' target and, unless ``dry_run``,
    make it: the notebook's one call that drives the robot (§II-D, Fig. 2 step 3).

    ``robot``: None (no robot: the plan starts from the generated dataset's start joints, or home,
    and nothing moves), a UR controller's host (an :class:`~histostudy.robot.RTDERobot` opened here
    and closed after) or a connected :class:`~histostudy.robot.Robot` (left open).

    The guard, as ``histostudy target``'s: the plan is made from the robot's present joints and
    checked (:func:`histostudy.lab.plan_targeting`: the target inside the CBCT, the inverse
    kinematics, the workspace) before anything moves; with ``dry_run`` nothing moves; otherwise
    :func:`histostudy.lab.execute_targeting` makes the one checked linear move at ``speed_mm_s``,
    refusing (ValueError, nothing moved) a robot no longer where the plan started.

    Args:
        calibration: the hand-eye calibration (:func:`calibration_section`'s).
        inputs: the lab's inputs (their target, C-arm mm; the generated dataset's start joints).
        volume: the CBCT the target lies in (C-arm frame).
        robot: None, a UR controller's host, or a connected robot.
        dry_run: True: plan and check only.
        speed_mm_s: the linear speed of the move, mm/s.

    Returns:
        The plan and what the move reached (:func:`histostudy.lab.execute_targeting`'s record),
        None when nothing moved.

    Raises:
        ValueError: ``dry_run`` not a bool, ``speed_mm_s`` not > 0, a plan refused (target outside
            the CBCT, unreachable, outside the workspace) or a robot no longer where the plan started.
        TypeError: ``robot`` of another type.
    """
    dry_run = _check_bool(dry_run, "dry_run")
    speed_mm_s = check_positive(speed_mm_s, "speed_mm_s", unit="mm/s")
    if robot is not None and not isinstance(robot, (str, Robot)):
        raise TypeError(f"robot must be None, a UR controller's host or a histostudy.robot.Robot, got "
                        f"{type(robot).__name__}")
    connected: Robot | None
    opened: Robot | None = None  # the robot this call connected to, and so closes
    if isinstance(robot, str):
        from histostudy.robot import RTDERobot

        opened = connected = RTDERobot(robot)
    else:
        connected = robot
    try:
        plan = target_plan(calibration, inputs, volume, None if connected is None else connected.joints())
        executed = (None if connected is None or dry_run
                    else execute_targeting(plan, connected, speed_mm_s=speed_mm_s))
    finally:
        if opened is not None:
            opened.close()
    return plan, executed


def target_part(volume: Volume, plan: TargetingPlan, executed: dict | None) -> SectionPart:
    """The target and the move (§II-D).

    Args:
        volume: the CBCT (C-arm frame).
        plan: :func:`drive_robot`'s plan.
        executed: what the move reached, or None when nothing moved.

    Returns:
        A part with table ``plan`` (:func:`plan_table`), figure ``cbct_target`` (the CBCT through the
        target) and values ``plan`` and, when the robot moved, ``executed``.
    """
    values = {"plan": plan.to_dict(), **({} if executed is None else {"executed": executed})}
    return SectionPart(tables={"plan": (plan_table(plan), "The planned move of the focal point onto the target.")},
                       figures={"cbct_target": (plot_cbct_target(volume, plan.target_mm),
                                                "The CBCT through the target (green).")}, values=values)


def stand_ins_part(inputs: LabInputs) -> SectionPart:
    """What stands in for the lab's equipment (nothing, with its own files).

    Args:
        inputs: the lab's inputs (``inputs.generated`` says whether the dataset was generated).

    Returns:
        A part with one ``(lab, synthetic)`` stand-in.
    """
    return SectionPart(stand_ins=tuple(stand_ins(inputs)))


def stand_ins(inputs: LabInputs) -> list[tuple[str, str]]:
    """``(lab, synthetic)``: what stands in for the lab's equipment (nothing, with its own files)."""
    return [("the lab's C-arm frames, CBCT, transducer CAD and UR5e",
             "the lab-like dataset of histostudy.study.your_data.lab_dataset (synthetic XA frames of the physical "
             "transducer model, a simulated CBCT, STL meshes exported from the parametric model); a dry run of the "
             "robot"
             if inputs.generated else "the lab's own files")]
