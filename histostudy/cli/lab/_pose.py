"""``histostudy pose``: a biplane pair of the lab's frames -> the transducer pose (§II-B.3-4)."""

from __future__ import annotations

import time

from ..console import Steps, add_command, elapsed_since, emit, fail, log
from ._inputs import WORLD_FRAME, check_frames, check_transducer, estimate_from_files, frame_options, model_from_args

__all__ = ["add_pose"]


def add_pose(sub, parents) -> None:
    pose = add_command(
        sub, "pose", parents, help="estimate the transducer pose from the lab's own frames (one per view)",
        description="Estimate the transducer's pose T_carm_transducer (4x4, mm, the C-arm frame = the CBCT's "
                    "world frame, DICOM LPS) from one frame per view: segmentation (U-Net), orientation, the "
                    "refinement of eq. 3 and the verdict. Writes the pose record as JSON (--output) and prints "
                    "its summary as one JSON line; exit status 1 when the verdict refuses the pose.",
        example="histostudy pose calibration/station_0/A.dcm calibration/station_0/B.dcm --output pose.json\n"
                "histostudy pose A.npy B.npy --views views.json --line-integrals --output pose.json")
    pose.add_argument("frames", nargs="+", metavar="FRAMES",
                      help="frame files: DICOM XA (views from their geometry tags unless --views), .npy, .png or .tif")
    frame_options(pose)
    pose.add_argument("--output", default="pose.json", help="where the pose is written as JSON (default pose.json)")
    pose.set_defaults(run=run_pose)


def run_pose(args) -> int:
    from histostudy.core import atomic_write_json
    from histostudy.pose import pose_record

    t0 = time.monotonic()
    try:
        study = check_frames(args.frames, args)  # every input read and checked before the models load
        check_transducer(args)
        with Steps(1, enabled=args.progress, label="pose") as steps:
            steps.step("reading the frames, segmenting, refining")
            result = estimate_from_files(args.frames, args)
    except (ValueError, TypeError, OSError) as exc:
        return fail("pose", exc)
    record = pose_record(result, args.frames, model=model_from_args(args))
    record["study_instance_uid"] = study  # what `histostudy target --pose` matches its calibration's with
    atomic_write_json(args.output, record)
    focal = ", ".join(f"{x:.2f}" for x in record["focal_point_mm"])
    verdict = "accepted" if record["accepted"] else "REFUSED: " + "; ".join(record["verdict"]["reasons"])
    log.info(f"focal point (C-arm frame, LPS, mm): {focal}; {verdict}; written to {args.output}")
    if record["half_turn"]["symmetric"]:
        axis = ", ".join(f"{x:.3f}" for x in record["half_turn"]["axis_carm"])
        log.info(f"orientation ambiguous by a half turn about the transducer's axis ({axis}, C-arm frame): the "
                 "transducer looks the same turned half about it, so no image tells the two readings apart; both "
                 "are in the record (T_carm_transducer, half_turn.T_carm_transducer_half_turn), with the same "
                 "focal point; `histostudy target --pose` plans with the one the robot reaches with less travel")
    emit({"command": "pose", "output": str(args.output), "accepted": record["accepted"],
          "focal_point_mm": record["focal_point_mm"], "frame": WORLD_FRAME,
          "reasons": record["verdict"]["reasons"], "wall_s": elapsed_since(t0)})
    return 0 if record["accepted"] else 1
