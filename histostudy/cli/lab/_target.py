"""``histostudy target``: a target in the CBCT (C-arm frame, LPS, mm; ``--target-frame ras`` or
``--target-voxel`` otherwise) -> a checked move of the focal point onto it, planned (a dry run, the
default) or, only with ``--execute`` and a robot, made (§II-D); with ``--pose`` its orientation is
kept, in the half-turn reading the robot reaches with less travel."""

from __future__ import annotations

import math
import time
from pathlib import Path

from ..console import add_command, elapsed_since, emit, fail, log
from ._inputs import WORLD_FRAME, residual_options, triple

__all__ = ["add_target"]

#: The axes ``--target`` may be given in: DICOM's (the world frame's) or NIfTI's and 3D Slicer's.
FRAMES = ("lps", "ras")
#: The fastest ``--speed-mm-s`` taken: the UR5e's tool speed limit (1 m/s, its user manual).
MAX_SPEED_MM_S = 1000.0
#: The units --target may be given in, with their size in mm.
UNITS_MM = {"mm": 1.0, "m": 1000.0}
#: A --target whose every coordinate is smaller than this (mm) but not all zero is, unless its unit
#: is named, refused as likely metres: the C-arm frame's origin is its isocentre, and a point
#: within a millimetre of it on every axis is far likelier a position in metres typed as mm.
METRES_LIKELY_BELOW_MM = 1.0


def add_target(sub, parents) -> None:
    tgt = add_command(
        sub, "target", parents,
        help="plan (default) or execute the move of the focal point onto a target in the CBCT",
        description="Plan the robot's move that puts the transducer's focal point on a target in the CBCT, "
                    "through the calibration of `histostudy calibrate`: inverse kinematics from the robot's "
                    "present joints and the workspace check. Nothing moves unless --execute and --robot are "
                    "given. Coordinates are the C-arm (CBCT world) frame's, DICOM LPS axes (+x the patient's "
                    "left, +y posterior, +z superior), mm; nibabel and 3D Slicer show RAS (x and y negated): give "
                    "such a point with --target-frame ras. Writes the plan (and what the robot did) as JSON "
                    "(--output), the target in LPS and in RAS, and prints the summary as one JSON line.",
        example="histostudy target --calibration calibration.json --target=2.5,-10.3,3.6 --cbct cbct.nii.gz\n"
                "histostudy target --calibration calibration.json --target=-2.5,10.3,3.6 --target-frame ras "
                "--cbct cbct.nii.gz\n"
                "histostudy target --calibration calibration.json --target-voxel 36,37,31 --cbct cbct.nii.gz \\\n"
                "    --pose pose.json --robot 127.0.0.1 --execute --speed-mm-s 50")
    tgt.add_argument("--calibration", required=True, help="the calibration JSON of `histostudy calibrate`")
    where = tgt.add_mutually_exclusive_group(required=True)
    where.add_argument("--target", type=triple, help="x,y,z in mm in the C-arm (CBCT world) frame, with the axes of "
                                                     "--target-frame (--target=-1,2,3 when x is negative)")
    where.add_argument("--target-voxel", type=triple,
                       help="i,j,k: a voxel of --cbct as its file indexes it: nibabel's (i, j, k) of the NIfTI array "
                            "(3D Slicer's IJK), or (column, row, slice) of a DICOM volume, its slices sorted along "
                            "their normal; converted through the CBCT's own geometry")
    tgt.add_argument("--target-unit", choices=UNITS_MM, default=None,
                     help="the unit of --target: mm (the default) or m (converted to mm); a --target within "
                          f"{METRES_LIKELY_BELOW_MM:g} mm of the isocentre on every axis but not at it (0.0025,-0.0103,"
                          "0.0036) is refused as likely typed in metres unless --target-unit names its unit")
    tgt.add_argument("--target-frame", choices=FRAMES, default=None,
                     help="the axes of --target: lps (the default: DICOM's, the frame of every histostudy file) or "
                          "ras (nibabel's affine, 3D Slicer: x and y negated, converted to LPS before planning)")
    tgt.add_argument("--cbct", default=None, help="the CBCT (NIfTI .nii/.nii.gz or a DICOM folder): the target "
                                                  "must lie inside it")
    tgt.add_argument("--pose", default=None,
                     help="a pose record whose orientation to keep (default: the transducer pointing straight down); "
                          "for a transducer that looks the same after a half turn about its axis, read as recorded "
                          "or turned half, whichever the robot reaches with less joint travel (the plan says which)")
    tgt.add_argument("--robot", default=None, metavar="HOST",
                     help="the UR controller (ur_rtde): the plan starts from its joints")
    mode = tgt.add_mutually_exclusive_group()
    mode.add_argument("--dry-run", action="store_true", help="plan only, move nothing (the default)")
    mode.add_argument("--execute", action="store_true", help="move the robot (needs --robot)")
    tgt.add_argument("--speed-mm-s", type=float, default=50.0,
                     help=f"linear speed of the move, > 0 and at most {MAX_SPEED_MM_S:g} mm/s (default 50 mm/s); "
                          "checked and recorded in a dry run too")
    residual_options(tgt)
    tgt.add_argument("--output", default="target.json", help="plan (and result) JSON (default target.json)")
    tgt.set_defaults(run=run_target)


def run_target(args) -> int:
    import json

    from histostudy.calibration import CalibrationError, HandEyeCalibration
    from histostudy.core import atomic_write_json, to_jsonable, world_frame_keys
    from histostudy.imaging import load_volume
    from histostudy.lab import execute_targeting, plan_targeting
    from histostudy.robot import RobotError

    t0 = time.monotonic()
    speed = args.speed_mm_s
    if not (math.isfinite(speed) and 0.0 < speed <= MAX_SPEED_MM_S):
        return fail("target", ValueError(f"--speed-mm-s must be a speed in mm/s, > 0 and at most {MAX_SPEED_MM_S:g} "
                                         f"(the UR5e's tool speed limit), got {speed!r}"))
    if args.execute and args.robot is None:
        return fail("target", ValueError("--execute moves a robot: name it with --robot HOST"))
    if args.target_unit is not None and args.target is None:
        return fail("target", ValueError(f"--target-unit {args.target_unit} gives the unit of --target x,y,z; "
                                         "--target-voxel is a voxel index, without a unit"))
    if args.target is not None and args.target_unit is None:
        largest = max(abs(float(v)) for v in args.target)
        if 0.0 < largest < METRES_LIKELY_BELOW_MM:
            typed = ",".join(f"{float(v):g}" for v in args.target)
            as_mm = ",".join(f"{1000.0 * float(v):g}" for v in args.target)
            return fail("target", ValueError(
                f"--target={typed} lies within {METRES_LIKELY_BELOW_MM:g} mm of the isocentre on every axis: it looks "
                f"like metres ({as_mm} mm?). Give it in mm, or name its unit: --target-unit m, or --target-unit mm "
                "if it is in mm"))
    if args.target_frame is not None and args.target is None:
        return fail("target", ValueError(f"--target-frame {args.target_frame} gives the axes of --target x,y,z; "
                                         "--target-voxel is a voxel of --cbct, in the CBCT's own geometry"))
    robot = None
    try:
        calibration_dict = json.loads(Path(args.calibration).read_text(encoding="utf-8"))
        calibration = HandEyeCalibration.from_dict(calibration_dict)
        calibration.check(args.max_focal_residual_mm, args.max_rotation_residual_deg)
        volume = None if args.cbct is None else load_volume(args.cbct)
        target, given_as = _target_lps(args, volume)
        start = None
        if args.robot is not None:
            from histostudy.robot import RTDERobot

            robot = RTDERobot(args.robot)
            start = robot.joints()
        if args.pose is None:
            plan = plan_targeting(calibration, target, volume=volume, start_joints_rad=start)
        else:
            plan = _plan_with_pose(args.pose, calibration, target, volume, start, args.calibration,
                                   calibration_dict.get("study_instance_uids") or [])
        executed = execute_targeting(plan, robot, speed_mm_s=args.speed_mm_s) if args.execute and robot else None
    except (CalibrationError, RobotError) as exc:
        return fail("target", exc, 1)
    except (ValueError, TypeError, KeyError, FileNotFoundError, OSError) as exc:
        return fail("target", exc)
    finally:
        if robot is not None:
            robot.close()
    planned = plan.to_dict()
    given = {"target_frame_given": given_as, "target_given": args.target_voxel if given_as == "voxel" else args.target,
             "target_unit_given": None if given_as == "voxel" else args.target_unit or "mm"}
    atomic_write_json(args.output, to_jsonable({"dry_run": not args.execute, "robot": args.robot,
                                                "speed_mm_s": speed,
                                                **world_frame_keys(angle="rad"), **given, "plan": planned,
                                                "executed": executed}))
    _log_plan(plan, planned, given_as, executed, args.output)
    emit({"command": "target", "output": str(args.output), "dry_run": not args.execute, "speed_mm_s": speed,
          "target_mm": plan.target_mm, "frame": WORLD_FRAME, "target_ras_mm": planned["target_ras_mm"], **given,
          "orientation_reading": plan.orientation_reading, "joint_travel_rad": plan.joint_travel_rad,
          "moved": executed is not None,
          "position_error_mm": None if executed is None else executed["position_error_mm"],
          "wall_s": elapsed_since(t0)})
    return 0


def _target_lps(args, volume):
    """The target in the world frame (LPS mm) and how it was given: ``lps``, ``ras`` or ``voxel``."""
    from histostudy.imaging import lps_from_ras

    if args.target is not None:
        frame = args.target_frame or "lps"
        given = [UNITS_MM[args.target_unit or "mm"] * float(v) for v in args.target]
        return (lps_from_ras(given)[0] if frame == "ras" else given), frame
    if volume is None:
        raise ValueError("--target-voxel needs --cbct: a voxel index means nothing without its volume")
    target = volume.file_voxel_to_world([args.target_voxel])[0]
    if not volume.contains(target)[0]:
        raise ValueError(f"--target-voxel {','.join(f'{v:g}' for v in args.target_voxel)} lies outside the CBCT volume "
                         f"{args.cbct!r}: at {target.round(3).tolist()} mm (LPS), beyond its voxel centres "
                         f"({volume.lower_mm.round(3).tolist()} to {volume.upper_mm.round(3).tolist()} mm)")
    return target, "voxel"


def _plan_with_pose(path, calibration, target, volume, start, calibration_path, calibration_studies):
    """The plan keeping the orientation of the pose record at ``path``, in the reading the robot
    reaches with less travel when its transducer looks the same after a half turn; a record of
    another study than ``calibration_studies`` (those of the calibration at ``calibration_path``)
    is refused."""
    from histostudy.lab import load_pose_record, plan_targeting_either_reading

    record = load_pose_record(path)
    if record["accepted"] is not True:
        reasons = (record.get("verdict") or {}).get("reasons") or ["no reason recorded"]
        raise ValueError(f"--pose {str(path)!r} is a pose its verdict refused ({'; '.join(map(str, reasons))}): "
                         "its orientation is not to be planned with; pose again")
    study = record.get("study_instance_uid")
    if study and calibration_studies and study not in calibration_studies:
        raise ValueError(f"--pose {str(path)!r} was acquired in study {study}, --calibration {str(calibration_path)!r} "
                         f"in {', '.join(map(str, calibration_studies))}: a calibration holds only while the robot's "
                         "base and the C-arm stay where it was made; calibrate in this study, or give a pose of the "
                         "calibration's")
    half_turn = record.get("half_turn")
    symmetric = half_turn.get("symmetric") if isinstance(half_turn, dict) else None
    if symmetric not in (True, False, None):
        raise ValueError(f"pose record {str(path)!r}: half_turn.symmetric must be true or false, got {symmetric!r}")
    return plan_targeting_either_reading(calibration, target, record["T_carm_transducer"], symmetric=symmetric,
                                         volume=volume, start_joints_rad=start)


def _log_plan(plan, planned: dict, given_as: str, executed, output) -> None:
    what = (f"moved: TCP {executed['position_error_mm']:.3f} mm from the commanded pose" if executed
            else "dry run: nothing moved (--execute --robot HOST moves the robot)")
    lps = [round(float(v), 2) for v in plan.target_mm]
    ras = [round(float(v), 2) for v in planned["target_ras_mm"]]
    log.info(f"target {lps} mm (C-arm frame, LPS; RAS {ras}; given as {given_as}): joints travel up to "
             f"{plan.joint_travel_rad:.3f} rad; {what}; written to {output}")
    if plan.orientation_reading is not None:
        log.info(f"the pose's orientation, {plan.orientation_reading}: {plan.orientation_reason}")
