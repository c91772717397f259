"""The lab's subcommands of ``histostudy`` (§II-B to §II-D on the lab's own files and robot):

- ``pose FRAMES`` — a biplane pair (DICOM XA, ``.npy``, ``.png``/``.tif``) -> the transducer pose;
- ``calibrate STATION ... --flange-poses F`` — per station a pose record of ``pose`` or a folder of
  its frames, with the flange poses the robot reported -> the hand-eye calibration (Daniilidis);
- ``target --calibration C --target x,y,z [--cbct V] [--robot HOST] [--execute]`` — a checked move
  of the focal point onto a target: planned (a dry run, the default) or, only with ``--execute``
  and a robot, made;
- ``listen --port N --views V`` — a DICOM C-STORE receiver of live C-arm frames -> one pose per
  biplane pair, as JSON lines, the newest pair posed and older waiting ones dropped
  (``--max-queued-pairs``), and a short line per pose on stdout (``--quiet``: none); on loopback
  unless ``--host`` says otherwise, from the senders ``--allow``/``--modalities`` list, over TLS
  with ``--tls-cert``/``--tls-key`` (``--tls-ca``: client certificates required).

Each writes its result as JSON (atomically: whole or not at all). Exit status 0 done, 1 refused
(a verdict, a calibration beyond its bound, an unreachable target), 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .study import _positive_int as positive_int  # the one check of a count argument

__all__ = ["add_parsers"]


def _triple(text: str) -> tuple[float, float, float]:
    import argparse

    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(abs(v) < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    return values


def add_parsers(sub, parents) -> None:
    """The lab's subcommands on the ``histostudy`` parser's ``sub``."""
    pose = sub.add_parser("pose", parents=parents,
                          help="estimate the transducer pose from the lab's own frames (one per view)")
    pose.add_argument("frames", nargs="+", help="frame files: DICOM XA (views from their geometry tags unless "
                                                "--views), .npy, .png or .tif")
    _frame_options(pose)
    pose.add_argument("--output", default="pose.json", help="where the pose is written as JSON (default pose.json)")
    pose.set_defaults(run=_pose)

    cal = sub.add_parser("calibrate", parents=parents,
                         help="hand-eye calibration of the robot to the C-arm from n >= 3 stations")
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
    _frame_options(cal)
    _residual_options(cal)
    cal.add_argument("--output", default="calibration.json", help="calibration JSON (default calibration.json)")
    cal.set_defaults(run=_calibrate)

    tgt = sub.add_parser("target", parents=parents,
                         help="plan (default) or execute the move of the focal point onto a target in the CBCT")
    tgt.add_argument("--calibration", required=True, help="the calibration JSON of `histostudy calibrate`")
    where = tgt.add_mutually_exclusive_group(required=True)
    where.add_argument("--target", type=_triple, help="x,y,z in the C-arm (CBCT world) frame, mm (--target=-1,2,3 "
                                                      "when x is negative)")
    where.add_argument("--target-voxel", type=_triple, help="i,j,k: a voxel of --cbct (x, y, z indices)")
    tgt.add_argument("--cbct", default=None, help="the CBCT (NIfTI .nii/.nii.gz or a DICOM folder): the target "
                                                  "must lie inside it")
    tgt.add_argument("--pose", default=None, help="a pose record whose orientation to keep (default: the transducer "
                                                  "pointing straight down)")
    tgt.add_argument("--robot", default=None, metavar="HOST",
                     help="the UR controller (ur_rtde): the plan starts from its joints")
    mode = tgt.add_mutually_exclusive_group()
    mode.add_argument("--dry-run", action="store_true", help="plan only, move nothing (the default)")
    mode.add_argument("--execute", action="store_true", help="move the robot (needs --robot)")
    tgt.add_argument("--speed-mm-s", type=float, default=50.0, help="linear speed of the move (default 50 mm/s)")
    _residual_options(tgt)
    tgt.add_argument("--output", default="target.json", help="plan (and result) JSON (default target.json)")
    tgt.set_defaults(run=_target)

    lis = sub.add_parser("listen", parents=parents,
                         help="receive live C-arm frames over DICOM (C-STORE) and write a pose per biplane pair")
    lis.add_argument("--port", type=int, required=True, help="TCP port to listen on (0: any free port)")
    lis.add_argument("--views", required=True, help="views JSON: one view per plane, named as the planes' "
                                                    "SeriesDescription")
    lis.add_argument("--host", default="127.0.0.1",
                     help="address to bind (default 127.0.0.1: this machine only; 0.0.0.0: every interface, e.g. "
                          "for the C-arm's network, with --allow or --modalities)")
    lis.add_argument("--ae-title", default="HISTOSTUDY", help="this receiver's AE title (default HISTOSTUDY)")
    lis.add_argument("--output", default="poses.jsonl", help="JSON lines, one pose per pair (default poses.jsonl)")
    lis.add_argument("--max-pairs", type=int, default=None, help="stop after this many pairs")
    lis.add_argument("--timeout-s", type=float, default=None, help="stop after this many seconds")
    lis.add_argument("--seed", type=int, default=0, help="seed of the estimates' random draws (default 0)")
    lis.add_argument("--fast", action=argparse.BooleanOptionalAction, default=True,
                     help="track on the region of the last pose (pose.Tracker(fast=True), the default: "
                          "docs/tracking.md); --no-fast: every pair on the full frames")
    lis.add_argument("--warm-up", action=argparse.BooleanOptionalAction, default=True,
                     help="run the tracker once on a synthetic pair before the first frame (pose.Tracker.warm_up, "
                          "the default), so the first pair does not wait for compiled kernels; the poses are the same")
    lis.add_argument("--max-queued-pairs", type=_queue_bound, default=1, metavar="N|all",
                     help="the most pairs waiting for a pose: a newer pair drops the oldest rather than fall behind "
                          "(counted in the stats; default 1: the newest pair only; all: keep every pair, for a cine "
                          "sent at once)")
    lis.add_argument("--allow", action="append", default=[], metavar="AE[@IP]",
                     help="a sender allowed: its calling AE title and, optionally, the IP address it must call from "
                          "(repeat for each; with --modalities, both lists). Others are rejected at association "
                          "(A-ASSOCIATE-RJ). "
                          "Default: any calling AE title, with a warning; the called AE title is checked always")
    lis.add_argument("--modalities", default=None, metavar="FILE",
                     help='JSON allow-list: {"modalities": {"carm_a": {"ae_title": "CARM_A", "host": '
                          '"192.168.10.21"}, ...}} (host optional)')
    lis.add_argument("--tls-cert", default=None, metavar="PEM", help="receive over TLS: this receiver's certificate")
    lis.add_argument("--tls-key", default=None, metavar="PEM", help="its private key (default: in --tls-cert's file)")
    lis.add_argument("--tls-ca", default=None, metavar="PEM",
                     help="CA certificate(s): every sender must present a certificate it signed (mutual TLS)")
    lis.add_argument("--quiet", action="store_true",
                     help="no line per pose on stdout (default: time, pair, kind, verdict, focal point, latency, "
                          "pairs dropped)")
    lis.set_defaults(run=_listen)


def _queue_bound(text: str) -> int | None:
    """``--max-queued-pairs``: an integer >= 1, or ``all`` (None: no bound)."""
    if text.strip().lower() == "all":
        return None
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1 or 'all', got {text!r}") from None


def _frame_options(parser) -> None:
    parser.add_argument("--views", default=None, help="views JSON file (histostudy.imaging.save_views): matched by "
                                                      "order, or by name = the frame file's stem")
    parser.add_argument("--frame-index", type=int, default=None, help="the frame of each multi-frame file (a cine)")
    parser.add_argument("--line-integrals", action="store_true",
                        help="the files hold line integrals already (default: intensities, converted with -log(I/I0))")
    parser.add_argument("--resample", action="store_true", help="resize frames of another size onto their view")
    parser.add_argument("--seed", type=int, default=0, help="seed of the estimate's random draws (default 0)")
    parser.add_argument("--transducer", default=None, metavar="DIR",
                        help="the transducer's CAD meshes, one file per feature class named after it (transducer.stl, "
                             "outer_boundary.stl, inner_boundary.stl, gaps.stl, screws.stl; mm, transducer frame); "
                             "default: the paper's digital model")


def _residual_options(parser) -> None:
    parser.add_argument("--max-focal-residual-mm", type=float, default=2.0,
                        help="the calibration's bound on each station's focal-point residual (default 2 mm)")
    parser.add_argument("--max-rotation-residual-deg", type=float, default=1.0,
                        help="the calibration's bound on each station's rotation residual (default 1 deg)")


def _fail(command: str, exc: BaseException, code: int = 2) -> int:
    print(f"histostudy {command}: {exc}", file=sys.stderr)
    return code


_MESH_SUFFIXES = (".stl", ".ply", ".obj", ".vtp")


def _model(args):
    """The transducer model of ``--transducer`` (cached on ``args``: calibrate estimates several poses)."""
    from histostudy.transducer import TransducerModel

    if args.transducer is None:
        return None
    if getattr(args, "_model", None) is None:
        folder = Path(args.transducer)
        if not folder.is_dir():
            raise FileNotFoundError(f"--transducer {str(folder)!r}: no such folder of meshes")
        meshes = {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in _MESH_SUFFIXES}
        if not meshes:
            raise ValueError(f"--transducer {str(folder)!r} holds no mesh files ({', '.join(_MESH_SUFFIXES)})")
        args._model = TransducerModel.from_meshes(meshes)
    return args._model


def _estimate(frames, args):
    from histostudy.pose import pose_from_files

    return pose_from_files(frames, args.views, frame_index=args.frame_index, line_integrals=args.line_integrals,
                           resample=args.resample, seed=args.seed, model=_model(args))


def _pose(args) -> int:
    from histostudy.core import atomic_write_json
    from histostudy.pose import pose_record

    try:
        result = _estimate(args.frames, args)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return _fail("pose", exc)
    record = pose_record(result, args.frames)
    atomic_write_json(args.output, record)
    focal = ", ".join(f"{x:.2f}" for x in record["focal_point_mm"])
    verdict = "accepted" if record["accepted"] else "REFUSED: " + "; ".join(record["verdict"]["reasons"])
    print(f"focal point (C-arm frame, mm): {focal}; {verdict}; written to {args.output}")
    return 0 if record["accepted"] else 1


_FRAME_SUFFIXES = (".dcm", ".dicom", ".npy", ".png", ".tif", ".tiff")


def _station_record(station: Path, args) -> dict:
    from histostudy.lab import load_pose_record
    from histostudy.pose import pose_record

    if station.is_dir():
        frames = sorted(p for p in station.iterdir() if p.suffix.lower() in _FRAME_SUFFIXES)
        if not frames:
            raise ValueError(f"station folder {str(station)!r} holds no frame files ({', '.join(_FRAME_SUFFIXES)})")
        return pose_record(_estimate(frames, args), frames)
    return load_pose_record(station)


def _calibrate(args) -> int:
    import json

    import numpy as np

    from histostudy.calibration import CalibrationError
    from histostudy.core import atomic_write_json, to_jsonable
    from histostudy.lab import accepted_stations, calibrate_from_poses, load_flange_poses

    try:
        flanges = load_flange_poses(args.flange_poses)
        nominal = None
        if args.nominal_mount is not None:
            nominal = np.asarray(json.loads(Path(args.nominal_mount).read_text())["T_flange_transducer"], float)
        records = []
        for station in map(Path, args.stations):
            record = _station_record(station, args)
            state = "accepted" if record["accepted"] else "REFUSED"
            print(f"station {station}: focal point {np.round(record['focal_point_mm'], 2).tolist()} mm, {state}")
            records.append(record)
        calibration = calibrate_from_poses(records, flanges, nominal_T_flange_transducer=nominal,
                                           max_focal_residual_mm=args.max_focal_residual_mm,
                                           max_rotation_residual_deg=args.max_rotation_residual_deg,
                                           on_refused="exclude" if args.exclude_refused else "raise")
    except CalibrationError as exc:
        return _fail("calibrate", exc, 1)
    except (ValueError, TypeError, KeyError, FileNotFoundError, OSError) as exc:
        return _fail("calibrate", exc)
    used = [args.stations[i] for i in accepted_stations(records)]
    atomic_write_json(args.output, to_jsonable({**calibration.to_dict(), "stations": list(args.stations),
                                                "used_stations": used}))
    print(f"calibrated on {calibration.n_poses} stations: focal residual max {calibration.max_focal_residual_mm:.3f} mm, "
          f"rotation residual max {calibration.max_rotation_residual_deg:.3f} deg; written to {args.output}")
    return 0


def _target(args) -> int:
    import json

    from histostudy.calibration import CalibrationError, HandEyeCalibration
    from histostudy.core import atomic_write_json, to_jsonable
    from histostudy.imaging import load_volume
    from histostudy.lab import execute_targeting, load_pose_record, plan_targeting
    from histostudy.robot import RobotError

    if args.execute and args.robot is None:
        return _fail("target", ValueError("--execute moves a robot: name it with --robot HOST"))
    robot = None
    try:
        calibration = HandEyeCalibration.from_dict(json.loads(Path(args.calibration).read_text(encoding="utf-8")))
        calibration.check(args.max_focal_residual_mm, args.max_rotation_residual_deg)
        volume = None if args.cbct is None else load_volume(args.cbct)
        if args.target_voxel is not None:
            if volume is None:
                raise ValueError("--target-voxel needs --cbct: a voxel index means nothing without its volume")
            target = volume.voxel_to_world([args.target_voxel])[0]
        else:
            target = args.target
        orientation = "down" if args.pose is None else load_pose_record(args.pose)["T_carm_transducer"]
        start = None
        if args.robot is not None:
            from histostudy.robot import RTDERobot

            robot = RTDERobot(args.robot)
            start = robot.joints()
        plan = plan_targeting(calibration, target, volume=volume, orientation=orientation, start_joints_rad=start)
        executed = execute_targeting(plan, robot, speed_mm_s=args.speed_mm_s) if args.execute else None
    except (CalibrationError, RobotError) as exc:
        return _fail("target", exc, 1)
    except (ValueError, TypeError, KeyError, FileNotFoundError, OSError) as exc:
        return _fail("target", exc)
    finally:
        if robot is not None:
            robot.close()
    atomic_write_json(args.output, to_jsonable({"dry_run": not args.execute, "robot": args.robot,
                                                "plan": plan.to_dict(), "executed": executed}))
    what = (f"moved: TCP {executed['position_error_mm']:.3f} mm from the commanded pose" if executed
            else "dry run: nothing moved (--execute --robot HOST moves the robot)")
    print(f"target {[round(float(v), 2) for v in plan.target_mm]} mm: joints travel up to "
          f"{plan.joint_travel_rad:.3f} rad; {what}; written to {args.output}")
    return 0


def _listen(args) -> int:
    from histostudy.imaging import load_views
    from histostudy.lab import AllowList, TLSConfig, listen, load_modalities, parse_allow

    def started(port: int) -> None:  # the bound port (--port 0: a free one), for whoever sends the frames
        print(f"listening on {args.host}:{port} as {args.ae_title}; poses to {args.output}", flush=True)
        senders = "any calling AE title (no --allow or --modalities)" if allow is None else \
            ", ".join(map(str, allow.modalities))
        link = "plain TCP" if tls is None else "TLS" + (", client certificates required" if tls.ca else "")
        print(f"senders allowed: {senders}; {link}", flush=True)

    try:
        listed = [parse_allow(text) for text in args.allow]
        if args.modalities is not None:
            listed += load_modalities(args.modalities).modalities
        allow = AllowList(tuple(listed)) if listed else None
        tls = None
        if (args.tls_key or args.tls_ca) and not args.tls_cert:
            raise ValueError("--tls-key and --tls-ca need --tls-cert: the certificate this receiver presents")
        if args.tls_cert:
            tls = TLSConfig(args.tls_cert, args.tls_key, args.tls_ca)
        views = load_views(args.views)
        stats = listen(views, port=args.port, host=args.host, ae_title=args.ae_title, output_path=args.output,
                       max_pairs=args.max_pairs, timeout_s=args.timeout_s, seed=args.seed,
                       max_queued_pairs=args.max_queued_pairs, fast=args.fast, warm_up=args.warm_up, on_start=started,
                       on_summary=None if args.quiet else lambda text: print(text, flush=True), allow=allow, tls=tls)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        return _fail("listen", exc)
    latency = stats["latency_s"]
    figures = ", ".join(f"{k} {latency[k]:.3f}" for k in ("p50", "p90", "p99", "max") if latency[k] is not None)
    print(f"listen: {stats['pairs_processed']} pairs posed ({stats['pairs_accepted']} accepted, "
          f"{stats['pairs_errors']} errors), {stats['pairs_skipped']} dropped; latency s: {figures or 'no pose'}")
    print(f"listen: {stats}")
    return 0
