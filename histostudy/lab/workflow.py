"""The lab's workflow on its own files and robot (§II-C, §II-D, Fig. 2): pose records and flange
poses in, a checked hand-eye calibration out; a target in the CBCT in, a checked robot move out,
planned unless the caller asks to execute it (the files: docs/your-data.md, "The workflow's files").
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from histostudy.calibration import HandEyeCalibration, calibrate_half_turns, target_orientation, tcp_for_target
from histostudy.core import to_jsonable, world_frame_keys
from histostudy.geometry import check_rigid, check_rotation, invert_transform
from histostudy.imaging import Volume, check_volume, ras_from_lps
from histostudy.robot import (
    HOME_JOINTS_RAD,
    Robot,
    UnreachablePoseError,
    Workspace,
    WorkspaceViolation,
    forward_kinematics,
    inverse_kinematics_closest,
    transform_from_pose,
)
from histostudy.transducer import HALF_TURN

__all__ = ["READINGS", "TargetingPlan", "accepted_stations", "calibrate_from_poses", "execute_targeting",
           "load_flange_poses", "load_pose_record", "plan_targeting", "plan_targeting_either_reading"]

#: The two readings of the pose of a transducer that looks the same after a half turn about its
#: axis (§II-B.4), as a plan's ``orientation_reading`` names them.
READINGS = ("as recorded", "half turn")

PLAN_SCHEMA = "histostudy.targeting_plan/1"


def _read_json(path: str | os.PathLike, what: str):
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} {str(path)!r}: no such file")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"{what} {str(path)!r} is not JSON: {exc}") from None


def load_pose_record(path: str | os.PathLike) -> dict:
    """A pose record of ``histostudy pose`` (:func:`histostudy.pose.pose_record`), checked.

    Args:
        path: the JSON file.

    Returns:
        The record (a dict) with ``T_carm_transducer`` as a rigid 4x4 numpy array (transducer ->
        C-arm, mm) and its ``accepted`` flag.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not JSON, without ``T_carm_transducer`` or ``accepted``, or a
            ``T_carm_transducer`` that is not a finite rigid 4x4 transform.
    """
    record = _read_json(path, "pose record")
    if not isinstance(record, dict) or "T_carm_transducer" not in record or "accepted" not in record:
        raise ValueError(f"pose record {str(path)!r} must be a JSON object with 'T_carm_transducer' and "
                         "'accepted', as `histostudy pose` writes it")
    record["T_carm_transducer"] = check_rigid(np.asarray(record["T_carm_transducer"], dtype=np.float64),
                                              f"{path}: T_carm_transducer")
    return record


def load_flange_poses(path: str | os.PathLike) -> list[np.ndarray]:
    """The flange poses a robot reported at the calibration stations, checked.

    Args:
        path: a JSON file holding ``T_base_flange`` (4x4 transforms, flange -> robot base, mm; read
            when present) or ``ur_pose`` (UR poses ``[x, y, z, rx, ry, rz]`` in m and axis-angle rad,
            as the pendant and ``getActualTCPPose`` give them, with the TCP offset at zero).

    Returns:
        ``T_base_flange`` per station (4x4 numpy arrays, mm).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not JSON, neither key, a pose that is not a finite rigid transform, or values in
            the wrong unit (:func:`~histostudy.lab.inputs.check_flange_pose_units`).
    """
    data = _read_json(path, "flange poses file")
    if not isinstance(data, dict) or not ({"T_base_flange", "ur_pose"} & set(data)):
        raise ValueError(f"flange poses file {str(path)!r} must be a JSON object with 'T_base_flange' "
                         "(4x4, mm) or 'ur_pose' ([x, y, z, rx, ry, rz] in m and rad) per station")
    from .inputs import check_flange_pose_units

    if "T_base_flange" in data:
        flanges = [check_rigid(np.asarray(T, dtype=np.float64), f"{path}: T_base_flange[{i}]")
                   for i, T in enumerate(data["T_base_flange"])]
    else:
        flanges = [transform_from_pose(p, f"{path}: ur_pose[{i}]") for i, p in enumerate(data["ur_pose"])]
    check_flange_pose_units(data, path)  # metres read as mm (or back) would fail only at the calibration's end
    return flanges


def calibrate_from_poses(pose_records: Sequence[dict], T_base_flange_list: Sequence, *,
                         nominal_T_flange_transducer=None, max_focal_residual_mm: float = 2.0,
                         max_rotation_residual_deg: float = 1.0, on_refused: str = "raise") -> HandEyeCalibration:
    """The hand-eye calibration of §II-C from the pose estimates at n >= 3 stations and the flange poses.

    Each estimate is read as itself or its half turn
    (:func:`~histostudy.calibration.calibrate_half_turns`), then the calibration is checked against
    the residual bounds (:meth:`~histostudy.calibration.HandEyeCalibration.check`). A station whose
    pose the verdict refused is never calibrated on.

    Args:
        pose_records: the stations' pose records (:func:`load_pose_record`), with
            ``T_carm_transducer`` (transducer -> C-arm, mm) and ``accepted``.
        T_base_flange_list: the flange poses at the same stations (flange -> robot base, 4x4, mm).
        nominal_T_flange_transducer: the mounting's nominal transform (transducer -> flange, 4x4,
            mm), which picks among the half-turn readings; None: none.
        max_focal_residual_mm: the bound on the focal point's residual (mm).
        max_rotation_residual_deg: the bound on the rotation's residual (deg).
        on_refused: ``"raise"`` (refuse the calibration, naming the refused stations: re-acquire their
            frames) or ``"exclude"`` (leave them out while at least 3 stations remain;
            :func:`accepted_stations` says which).

    Returns:
        The checked :class:`~histostudy.calibration.HandEyeCalibration`.

    Raises:
        ValueError: the lists differ in length, a bad ``on_refused``, or refused stations (with
            ``"raise"``, or fewer than 3 left).
        histostudy.calibration.CalibrationError: residuals beyond the bounds.
    """
    records = list(pose_records)
    flanges = list(T_base_flange_list)
    if len(records) != len(flanges):
        raise ValueError(f"pose_records and T_base_flange_list must pair up station by station, got "
                         f"{len(records)} pose records and {len(flanges)} flange poses")
    if on_refused not in ("raise", "exclude"):
        raise ValueError(f"on_refused must be 'raise' or 'exclude', got {on_refused!r}")
    used = accepted_stations(records)
    refused = sorted(set(range(len(records))) - set(used))
    if refused and (on_refused == "raise" or len(used) < 3):
        left = "" if on_refused == "raise" else f" and only {len(used)} stations remain (3 needed)"
        raise ValueError(f"pose_records {refused}: the pose estimate's verdict refused the fit{left}; re-acquire the "
                         "frames of those stations rather than calibrate on them")
    C = [np.asarray(records[i]["T_carm_transducer"], dtype=np.float64) for i in used]
    calibration = calibrate_half_turns([flanges[i] for i in used], C,
                                       nominal_T_flange_transducer=nominal_T_flange_transducer)
    return calibration.check(max_focal_residual_mm, max_rotation_residual_deg)


def accepted_stations(pose_records: Sequence[dict]) -> list[int]:
    """The stations a calibration uses.

    Args:
        pose_records: the stations' pose records.

    Returns:
        The indices of the records whose verdict accepted the fit (``accepted`` true).
    """
    return [i for i, r in enumerate(pose_records) if r.get("accepted", False)]


@dataclass(frozen=True, eq=False)
class TargetingPlan:
    """A checked move of the focal point onto a target (§II-D, Fig. 2 step 3); mm, rad, 4x4 transforms.

    Made by :func:`plan_targeting` (never outside the workspace); :meth:`to_dict` gives its JSON, with
    the ``frame`` and ``target_ras_mm`` (the target with RAS axes, as nibabel and 3D Slicer show it).

    Args:
        target_mm: the target (C-arm frame, mm).
        R_carm_transducer: the transducer's orientation at the target (transducer -> C-arm, 3x3).
        T_flange_tcp: the TCP the move aims, the calibrated focal point (TCP -> flange).
        T_base_tcp: the commanded TCP pose (TCP -> robot base).
        T_base_flange: the commanded flange pose (flange -> robot base).
        start_joints_rad: where the plan starts from: the robot's joints, or the home configuration
            for a plan made without a robot (rad).
        joints_rad: the inverse-kinematics solution nearest them (rad).
        joint_travel_rad: the largest joint move (rad).
        workspace_ok: always True (a plan outside the workspace is not made).
        orientation_reading: one of ``READINGS`` (:mod:`.workflow`), None for an orientation not read
            off a pose.
        orientation_reason: why that reading (:func:`plan_targeting_either_reading`).
    """

    target_mm: np.ndarray
    R_carm_transducer: np.ndarray
    T_flange_tcp: np.ndarray
    T_base_tcp: np.ndarray
    T_base_flange: np.ndarray
    start_joints_rad: np.ndarray
    joints_rad: np.ndarray
    joint_travel_rad: float
    workspace_ok: bool = True
    orientation_reading: str | None = None
    orientation_reason: str | None = None

    def to_dict(self) -> dict:
        return to_jsonable({"schema": PLAN_SCHEMA, **world_frame_keys(angle="rad"),
                            **{k: getattr(self, k) for k in self.__dataclass_fields__},
                            "target_ras_mm": ras_from_lps(self.target_mm)[0]})


def _orientation(calibration: HandEyeCalibration, orientation) -> np.ndarray:
    if orientation is None or (isinstance(orientation, str) and orientation == "down"):
        return target_orientation(calibration)
    o = np.asarray(orientation, dtype=object if isinstance(orientation, str) else np.float64)
    if o.shape == (4, 4):
        return check_rigid(o, "orientation")[:3, :3]
    if o.shape == (3, 3):
        return check_rotation(o, "orientation")
    raise ValueError(f"orientation must be 'down', a 3x3 R_carm_transducer or a 4x4 T_carm_transducer, "
                     f"got {orientation!r}")


def plan_targeting(calibration: HandEyeCalibration, target_mm, *, volume: Volume | None = None,
                   orientation="down", start_joints_rad=None, workspace: Workspace | None = None) -> TargetingPlan:
    """Plan the move that puts the calibrated focal point on ``target_mm`` (§II-D).

    Args:
        calibration: the hand-eye calibration (:func:`calibrate_from_poses`).
        target_mm: the target, 3 numbers (C-arm frame, mm: the CBCT's world coordinates, the CBCT
            being taken by the same C-arm).
        volume: the CBCT; when given, the target must lie inside it.
        orientation: ``"down"`` (propagation straight down,
            :func:`~histostudy.calibration.target_orientation`), or a 3x3 ``R_carm_transducer`` / 4x4
            ``T_carm_transducer`` to keep (e.g. the present pose).
        start_joints_rad: the robot's present joints (rad; default: the home configuration).
        workspace: the workspace the move must stay in; default ``Workspace()``.

    Returns:
        The :class:`TargetingPlan`.

    Raises:
        TypeError: ``calibration`` not a HandEyeCalibration.
        ValueError: a target that is not 3 finite numbers or lies outside ``volume``, or a bad
            ``orientation``.
        histostudy.robot.UnreachablePoseError: no joint solution reaches the pose.
        histostudy.robot.WorkspaceViolation: the move leaves the workspace.
    """
    if not isinstance(calibration, HandEyeCalibration):
        raise TypeError(f"calibration must be a HandEyeCalibration, got {type(calibration).__name__}")
    target = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target_mm must be 3 finite numbers (C-arm frame, mm), got {target_mm!r}")
    if volume is not None:
        volume = check_volume(volume)
        if not volume.contains(target)[0]:
            raise ValueError(f"target_mm={target.round(3).tolist()} lies outside the CBCT volume (voxel centres "
                             f"span {volume.lower_mm.round(3).tolist()} to {volume.upper_mm.round(3).tolist()} mm)")
    R = _orientation(calibration, orientation)
    T_flange_tcp = calibration.T_flange_transducer.copy()
    T_base_tcp = tcp_for_target(calibration, target, R, T_flange_tcp)
    T_base_flange = T_base_tcp @ invert_transform(T_flange_tcp)
    start = np.asarray(HOME_JOINTS_RAD if start_joints_rad is None else start_joints_rad, dtype=np.float64)
    joints = inverse_kinematics_closest(T_base_flange, start)
    # A guard on the kinematics themselves: the IK solution must reproduce the commanded flange.
    if not np.allclose(forward_kinematics(joints), T_base_flange, atol=1e-6):
        raise RuntimeError("inverse kinematics gave joints whose forward kinematics miss the commanded flange")
    (workspace or Workspace()).check(T_base_tcp, T_base_flange)
    return TargetingPlan(target_mm=target, R_carm_transducer=R, T_flange_tcp=T_flange_tcp, T_base_tcp=T_base_tcp,
                         T_base_flange=T_base_flange, start_joints_rad=start, joints_rad=joints,
                         joint_travel_rad=float(np.max(np.abs(joints - start))))


def plan_targeting_either_reading(calibration: HandEyeCalibration, target_mm, T_carm_transducer, *,
                                  symmetric: bool | None = True, volume: Volume | None = None,
                                  start_joints_rad=None, workspace: Workspace | None = None) -> TargetingPlan:
    """:func:`plan_targeting` keeping a recorded pose's orientation, read as recorded or turned half
    about the transducer's axis (:data:`~histostudy.transducer.HALF_TURN`, §II-B.4).

    Where the transducer looks the same both ways no image told the readings apart, and both keep the
    beam axis and put the focal point on the target: of those the robot can reach (inverse kinematics,
    workspace), the one of smaller joint travel from ``start_joints_rad`` is planned (as recorded on a
    tie). The plan's ``orientation_reading`` says which reading, and ``orientation_reason`` why.

    Args:
        calibration: the hand-eye calibration.
        target_mm: the target (C-arm frame, mm).
        T_carm_transducer: the recorded pose (4x4, transducer -> C-arm, mm) or rotation (3x3).
        symmetric: whether the transducer looks the same after a half turn (a pose record's
            ``half_turn.symmetric``); None where the record does not say (read as symmetric, as the
            paper's transducer is); False: planned as recorded.
        volume, start_joints_rad, workspace: as :func:`plan_targeting`'s.

    Returns:
        The :class:`TargetingPlan` of the reading chosen.

    Raises:
        ValueError: a bad ``symmetric`` or ``T_carm_transducer``, or as :func:`plan_targeting`.
        histostudy.robot.UnreachablePoseError, histostudy.robot.WorkspaceViolation: no reading can be
            reached (the message gives each reading's reason).
    """
    if symmetric not in (True, False, None):
        raise ValueError(f"symmetric must be True, False or None (not recorded), got {symmetric!r}")
    if isinstance(T_carm_transducer, str):
        raise ValueError(f"T_carm_transducer must be a 4x4 transform or a 3x3 rotation, got {T_carm_transducer!r}")
    R = _orientation(calibration, T_carm_transducer)
    options = dict(volume=volume, start_joints_rad=start_joints_rad, workspace=workspace)
    if symmetric is False:
        return replace(plan_targeting(calibration, target_mm, orientation=R, **options),
                       orientation_reading=READINGS[0],
                       orientation_reason="the transducer does not look the same after a half turn about its axis: "
                                          "its recorded orientation is not ambiguous")
    plans, refused = {}, {}
    for reading, R_reading in zip(READINGS, (R, R @ HALF_TURN)):
        try:
            plans[reading] = plan_targeting(calibration, target_mm, orientation=R_reading, **options)
        except (UnreachablePoseError, WorkspaceViolation) as exc:
            refused[reading] = exc
    if not plans:
        first = refused[READINGS[0]]
        raise type(first)("neither reading of the pose reaches the target: " + "; ".join(
            f"{reading}: {exc}" for reading, exc in refused.items())) from first
    chosen = min(plans, key=lambda reading: plans[reading].joint_travel_rad)  # min keeps READINGS' order on a tie
    other = next(reading for reading in READINGS if reading != chosen)
    why = (f"the robot cannot take the other reading ({other}): {type(refused[other]).__name__}: {refused[other]}"
           if other in refused else f"{plans[chosen].joint_travel_rad:.3f} rad of joint travel, against "
                                    f"{plans[other].joint_travel_rad:.3f} rad for the other reading ({other})")
    unsaid = "" if symmetric else " (the pose record does not say; read as the paper's transducer, which does)"
    reason = (f"the transducer looks the same after a half turn about its axis{unsaid}, so both readings put the "
              f"focal point on the target; {chosen} chosen: {why}")
    return replace(plans[chosen], orientation_reading=chosen, orientation_reason=reason)


def execute_targeting(plan: TargetingPlan, robot: Robot, *, speed_mm_s: float = 50.0,
                      max_start_deviation_rad: float = 1e-3) -> dict:
    """Move ``robot`` along ``plan``: set the TCP, then one linear move onto ``plan.T_base_tcp``.

    Args:
        plan: a :class:`TargetingPlan` (:func:`plan_targeting`).
        robot: the robot (a :class:`~histostudy.robot.Robot`).
        speed_mm_s: the linear move's speed (mm/s).
        max_start_deviation_rad: how far (rad, any joint) the robot may be from the plan's start.

    Returns:
        A JSON-ready dict: ``T_base_tcp_reached`` (4x4, mm), ``position_error_mm`` (its distance from
        the commanded one) and ``joints_rad`` after the move.

    Raises:
        TypeError: ``plan`` not a TargetingPlan.
        ValueError: the robot is no longer where the plan started (nothing moved): plan again from
            where it is.
    """
    if not isinstance(plan, TargetingPlan):
        raise TypeError(f"plan must be a TargetingPlan, got {type(plan).__name__}")
    joints = np.asarray(robot.joints(), dtype=np.float64)
    deviation = float(np.max(np.abs(joints - plan.start_joints_rad)))
    if deviation > max_start_deviation_rad:
        raise ValueError(f"the robot's joints {joints.round(4).tolist()} rad differ from the plan's start "
                         f"{plan.start_joints_rad.round(4).tolist()} by {deviation:.4f} rad > "
                         f"max_start_deviation_rad={max_start_deviation_rad}: plan again from where it is")
    robot.set_tcp(plan.T_flange_tcp)
    reached = np.asarray(robot.move_linear(plan.T_base_tcp, speed_mm_s), dtype=np.float64)
    return to_jsonable({"T_base_tcp_reached": reached,
                        "position_error_mm": float(np.linalg.norm(reached[:3, 3] - plan.T_base_tcp[:3, 3])),
                        "joints_rad": robot.joints()})
