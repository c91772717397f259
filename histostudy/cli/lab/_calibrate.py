"""``histostudy calibrate``: per station a pose (a record or the station's frames) and the flange
pose the robot reported -> the hand-eye calibration (Daniilidis, §II-C)."""

from __future__ import annotations

import time
from pathlib import Path

from ..console import Steps, add_command, elapsed_since, emit, fail, log
from ._inputs import (
    FRAME_SUFFIXES,
    WORLD_FRAME,
    check_frames,
    check_transducer,
    estimate_from_files,
    frame_options,
    model_from_args,
    residual_options,
)

__all__ = ["add_calibrate"]


def add_calibrate(sub, parents) -> None:
    cal = add_command(
        sub, "calibrate", parents, help="hand-eye calibration of the robot to the C-arm from n >= 3 stations",
        description="Calibrate the robot to the C-arm (AX = XB, Daniilidis) from n >= 3 stations: at each, the "
                    "transducer's pose in the C-arm frame (a pose record of `histostudy pose`, or a folder of the "
                    "station's frames, estimated here) and the flange pose the robot reported. Writes "
                    "T_carm_base and T_flange_transducer (4x4, mm) as JSON (--output) and prints the summary as "
                    "one JSON line; exit status 1 when a station is refused or a residual exceeds its bound.",
        example="histostudy calibrate calibration/station_* --flange-poses calibration/flange_poses.json \\\n"
                "    --output calibration.json")
    cal.add_argument("stations", nargs="+",
                     help="per station, in the order of --flange-poses: a pose record of `histostudy pose`, or a "
                          "folder holding the station's frame files (estimated here)")
    cal.add_argument("--flange-poses", required=True,
                     help="JSON with 'T_base_flange' (4x4, mm) or 'ur_pose' ([x,y,z,rx,ry,rz] m, rad) per station")
    cal.add_argument("--nominal-mount", default=None,
                     help="JSON with 'T_flange_transducer' (4x4, mm): the mount as designed; picks the transducer's "
                          "half turn (default: the first station's reading)")
    cal.add_argument("--exclude-refused", action="store_true",
                     help="leave out stations whose pose the verdict refused, if 3 remain (default: refuse to "
                          "calibrate; re-acquire those stations)")
    frame_options(cal)
    residual_options(cal)
    cal.add_argument("--output", default="calibration.json", help="calibration JSON (default calibration.json)")
    cal.set_defaults(run=run_calibrate)


def _station_input(station: Path, args) -> tuple[list[Path] | dict, str | None]:
    """A station's frame files (its folder's, each checked as the estimate will read it), or its
    pose record (read and checked); and the study they were acquired in (StudyInstanceUID, or None)."""
    from histostudy.lab import load_pose_record

    if station.is_dir():
        frames = sorted(p for p in station.iterdir() if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES)
        if not frames:
            raise ValueError(f"station folder {str(station)!r} holds no frame files ({', '.join(FRAME_SUFFIXES)})")
        return frames, check_frames(frames, args, label=f"station {str(station)!r}: frame file")
    if not station.exists():
        raise FileNotFoundError(f"station {str(station)!r}: no such folder (of the station's frames) or pose record")
    if station.suffix.lower() in FRAME_SUFFIXES:
        raise ValueError(f"station {str(station)!r} is a frame file: give the station's folder (its frames), or a "
                         "pose record of `histostudy pose`")
    record = load_pose_record(station)
    if "focal_point_mm" not in record:  # what each station's line on stderr reports
        raise ValueError(f"pose record {str(station)!r} lacks 'focal_point_mm', which `histostudy pose` writes")
    return record, record.get("study_instance_uid")


def _flange_poses(args) -> list:
    """``--flange-poses``, read and judged plausible (:func:`histostudy.lab.load_flange_poses`): one
    per station."""
    from histostudy.lab import load_flange_poses

    try:
        flanges = load_flange_poses(args.flange_poses)
    except TypeError as exc:  # a key's value that is no list of poses
        raise ValueError(f"--flange-poses {args.flange_poses!r}: expected a list of poses, one per station, under "
                         f"'T_base_flange' (4x4, mm) or 'ur_pose' ([x, y, z, rx, ry, rz] in m and rad) "
                         f"({exc})") from None
    except (ValueError, OSError) as exc:
        raise type(exc)(f"--flange-poses: {exc}") from None
    n = len(args.stations)
    if len(flanges) != n:
        raise ValueError(f"--flange-poses {args.flange_poses!r} holds {len(flanges)} flange poses for the {n} stations "
                         "given: one per station, in the stations' order")
    return flanges


def _nominal_mount(path):
    """``--nominal-mount``'s ``T_flange_transducer`` (4x4, mm, rigid), or None when not given."""
    import json

    import numpy as np

    from histostudy.geometry import check_rigid

    if path is None:
        return None
    if not Path(path).is_file():
        raise FileNotFoundError(f"--nominal-mount {path!r}: no such file")
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"--nominal-mount {path!r} is not JSON: {exc}") from None
    if not isinstance(data, dict) or "T_flange_transducer" not in data:
        raise ValueError(f"--nominal-mount {path!r} must be a JSON object with 'T_flange_transducer' (4x4, mm)")
    try:
        return check_rigid(np.asarray(data["T_flange_transducer"], dtype=np.float64),
                           f"--nominal-mount {path!r}: T_flange_transducer")
    except (TypeError, ValueError) as exc:
        raise ValueError(str(exc)) from None


def _checked_inputs(args) -> tuple[list, list, object]:
    """Every input of a calibration read and checked before the first pose estimate: the stations
    (their frame files or pose records, each with its study), the flange poses (one per station, in plausible units), at
    least 3 stations, the residual bounds, the nominal mount and the transducer's meshes."""
    import math

    inputs = [_station_input(Path(station), args) for station in args.stations]
    if len(inputs) < 3:
        raise ValueError(f"calibrate needs at least 3 stations (AX = XB is solved from the motions between them), "
                         f"got {len(inputs)}")
    flanges = _flange_poses(args)
    for flag, bound in (("--max-focal-residual-mm", args.max_focal_residual_mm),
                        ("--max-rotation-residual-deg", args.max_rotation_residual_deg)):
        if not (math.isfinite(bound) and bound > 0):
            raise ValueError(f"{flag} {bound!r}: expected a finite bound > 0")
    nominal = _nominal_mount(args.nominal_mount)
    check_transducer(args)
    return inputs, flanges, nominal


def _refusal(args, records: list) -> str | None:
    """Why the stations the verdict refused stop the calibration, or None when they do not."""
    refused = [args.stations[i] for i, record in enumerate(records) if not record["accepted"]]
    if not refused:
        return None
    if not args.exclude_refused:
        return (f"the pose verdict refused station(s) {refused}: re-acquire their frames, or leave them out with "
                "--exclude-refused")
    left = len(records) - len(refused)
    return None if left >= 3 else (f"the pose verdict refused station(s) {refused}, and only {left} stations remain "
                                   "(3 needed): re-acquire their frames")


def run_calibrate(args) -> int:
    import numpy as np

    from histostudy.calibration import CalibrationError
    from histostudy.core import atomic_write_json, to_jsonable
    from histostudy.lab import accepted_stations, calibrate_from_poses
    from histostudy.pose import pose_record

    t0 = time.monotonic()
    try:
        inputs, flanges, nominal = _checked_inputs(args)
        records = []
        with Steps(len(args.stations), enabled=args.progress, label="calibrate: stations") as steps:
            for station, (given, _) in zip(args.stations, inputs):
                steps.step(station)
                record = (given if isinstance(given, dict) else
                          pose_record(estimate_from_files(given, args), given, model=model_from_args(args)))
                state = "accepted" if record["accepted"] else "REFUSED"
                log.info(f"station {station}: focal point {np.round(record['focal_point_mm'], 2).tolist()} mm, {state}")
                records.append(record)
        if (refusal := _refusal(args, records)) is not None:
            return fail("calibrate", refusal, 1)
        calibration = calibrate_from_poses(records, flanges, nominal_T_flange_transducer=nominal,
                                           max_focal_residual_mm=args.max_focal_residual_mm,
                                           max_rotation_residual_deg=args.max_rotation_residual_deg,
                                           on_refused="exclude" if args.exclude_refused else "raise")
    except CalibrationError as exc:
        # a flange file of another session fails every station alike: name the file
        return fail("calibrate", f"{exc} (--flange-poses {args.flange_poses!r}: the robot's poses at these "
                                 f"stations, in the order given?)", 1)
    except (ValueError, TypeError, KeyError, FileNotFoundError, OSError) as exc:
        return fail("calibrate", exc)
    used = [args.stations[i] for i in accepted_stations(records)]
    atomic_write_json(args.output, to_jsonable({**calibration.to_dict(), "frame": WORLD_FRAME,
                                                "stations": list(args.stations), "used_stations": used,
                                                # what `histostudy target --pose` matches a pose's study with
                                                "study_instance_uids": sorted({s for _, s in inputs if s})}))
    log.info(f"calibrated on {calibration.n_poses} stations: focal residual max "
             f"{calibration.max_focal_residual_mm:.3f} mm, rotation residual max "
             f"{calibration.max_rotation_residual_deg:.3f} deg; written to {args.output}")
    emit({"command": "calibrate", "output": str(args.output), "n_stations": calibration.n_poses,
          "used_stations": used, "max_focal_residual_mm": calibration.max_focal_residual_mm,
          "max_rotation_residual_deg": calibration.max_rotation_residual_deg, "frame": WORLD_FRAME,
          "wall_s": elapsed_since(t0)})
    return 0
