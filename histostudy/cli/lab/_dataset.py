"""``histostudy lab-dataset``: a generated lab-like dataset (XA stations and cine, flange poses, a
CBCT, the transducer's meshes) to try the lab's commands on
(:func:`histostudy.study.your_data.lab_dataset.write_lab_dataset`)."""

from __future__ import annotations

import time

from ..console import Steps, add_command, elapsed_since, emit, fail, log
from ._inputs import positive_int

__all__ = ["add_lab_dataset"]


def add_lab_dataset(sub, parents) -> None:
    data = add_command(
        sub, "lab-dataset", parents, help="write a generated lab-like dataset to try the lab's commands on",
        description="Write what a lab hands the commands, generated from one synthetic set-up: views.json, "
                    "calibration/station_K/{A,B}.dcm (DICOM XA with geometry tags) and "
                    "calibration/flange_poses.json, cine/{A,B}.dcm (a biplane XA cine), cbct.nii.gz, "
                    "transducer/*.stl, dataset.json (what each file is and a suggested target) and truth.json "
                    "(the synthetic truth, for measuring errors). The same seed writes the same files.",
        example="histostudy lab-dataset my_lab\nhistostudy lab-dataset my_lab --seed 7 --cine-frames 8")
    data.add_argument("folder", help="where to write the dataset (created; files of the same names are replaced)")
    data.add_argument("--seed", type=int, default=20231125, help="seed of every draw (default 20231125)")
    data.add_argument("--cine-frames", type=positive_int, default=4, help="frames of the cine (default 4)")
    data.set_defaults(run=run_lab_dataset)


def run_lab_dataset(args) -> int:
    from histostudy.study.your_data.lab_dataset import write_lab_dataset

    t0 = time.monotonic()
    try:
        with Steps(1, enabled=args.progress, label="lab-dataset") as steps:
            steps.step("rendering the stations, the cine and the CBCT")
            lab = write_lab_dataset(args.folder, seed=args.seed, n_cine_frames=args.cine_frames)
    except (ValueError, OSError) as exc:
        return fail("lab-dataset", exc)
    log.info(f"lab-like dataset written to {lab.folder}: {len(lab.calibration_frames)} stations, a "
             f"{lab.n_cine_frames}-frame cine, the CBCT and the transducer's meshes (dataset.json says what each is)")
    emit({"command": "lab-dataset", "folder": str(lab.folder), "seed": args.seed,
          "n_stations": len(lab.calibration_frames), "n_cine_frames": lab.n_cine_frames,
          "suggested_target_mm": lab.target_mm, "manifest": str(lab.manifest), "wall_s": elapsed_since(t0)})
    return 0
