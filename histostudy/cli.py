"""The ``histostudy`` command: ``histostudy reproduce --profile smoke``, ``histostudy train segmentation``,
``histostudy pose A.dcm B.dcm`` (the lab's own frames), ``histostudy report`` and friends."""

from __future__ import annotations

import argparse
import signal
import sys

from .reporting import PROFILE_NAMES, load_profile

__all__ = ["main"]


def _profile(value: str):
    try:
        return load_profile(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(prog="histostudy", description=__doc__.strip().splitlines()[0])
    parser.add_argument("--version", action="version", version=f"histostudy {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    rep = sub.add_parser("reproduce", help="run the study notebooks through papermill and write the report")
    rep.add_argument("--profile", type=_profile, default="smoke",
                     help=f"one of {', '.join(PROFILE_NAMES)} or a .toml file (default: smoke)")
    rep.add_argument("--only", nargs="+", metavar="NAME",
                     help="run only these notebooks (stem, number such as 01, or name part)")
    rep.add_argument("--output", default="reports", help="output folder (default: reports)")
    rep.add_argument("--notebooks", default=None, help="notebook folder (default: the repository's notebooks/)")
    rep.add_argument("--no-progress", action="store_true", help="no per-cell progress bar")

    tr = sub.add_parser("train", help="train a learned stage (U-Net or VGG19) on hybrid images and export its weights")
    tr.add_argument("task", choices=("segmentation", "orientation"))
    tr.add_argument("--profile", type=_profile, default="standard",
                    help=f"one of {', '.join(PROFILE_NAMES)} or a .toml file with [training.<task>] (default: standard)")
    tr.add_argument("--run-dir", default=None,
                    help="checkpoint folder (default: <cache>/runs/<task>-<profile>; an interrupted run resumes there)")
    tr.add_argument("--models-dir", default=None, help="where the best weights are exported (default: data/models)")
    tr.add_argument("--no-resume", action="store_true", help="start afresh even if the run folder holds a checkpoint")
    tr.add_argument("--no-export", action="store_true", help="keep the weights in the run folder only")
    tr.add_argument("--max-minutes", type=float, default=None, help="override the profile's wall-time budget")
    tr.add_argument("--threads", type=int, default=None, help="torch CPU threads (override)")
    tr.add_argument("--init-weights", default=None,
                    help="start from this checkpoint's network (same config) instead of random weights")
    tr.add_argument("--render-workers", type=int, default=1,
                    help="render the profile's uncached training and validation frames (the fine-tune's too) in "
                         "this many processes before training (default 1: the training loop renders them as it "
                         "first needs them)")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")

    pose = sub.add_parser("pose", help="estimate the transducer pose from the lab's own frames (one per view)")
    pose.add_argument("frames", nargs="+", help="frame files: DICOM XA (views from their geometry tags unless "
                                                "--views), .npy, .png or .tif")
    pose.add_argument("--views", default=None, help="views JSON file (histostudy.imaging.save_views): matched by "
                                                    "order, or by name = the frame file's stem")
    pose.add_argument("--frame-index", type=int, default=None, help="the frame of each multi-frame file (a cine)")
    pose.add_argument("--line-integrals", action="store_true",
                      help="the files hold line integrals already (default: intensities, converted with -log(I/I0))")
    pose.add_argument("--resample", action="store_true", help="resize frames of another size onto their view")
    pose.add_argument("--seed", type=int, default=0, help="seed of the estimate's random draws (default 0)")
    pose.add_argument("--output", default="pose.json", help="where the pose is written as JSON (default pose.json)")

    rebuild = sub.add_parser("report", help="rebuild REPORT.md and report.html from a reproduce output folder")
    rebuild.add_argument("--output", default="reports", help="the folder reproduce wrote (default: reports)")

    prof = sub.add_parser("profiles", help="list the built-in profiles")
    prof.set_defaults(command="profiles")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "profiles":
        for name in PROFILE_NAMES:
            p = load_profile(name)
            print(f"{p.name:9s} seed {p.seed}  {p.description}")
        return 0
    if args.command == "train":
        return _train(args)
    if args.command == "pose":
        return _pose(args)
    if args.command == "report":
        return _report(args)
    if args.command == "reproduce":
        from .reporting import NotebookFailed, StudyInterrupted, run_study

        try:
            run = run_study(args.profile, args.output, only=args.only, notebooks_dir=args.notebooks,
                            progress=not args.no_progress)
        except NotebookFailed as exc:
            print(f"histostudy reproduce: {exc}", file=sys.stderr)
            return 1
        except StudyInterrupted as exc:
            print(f"histostudy reproduce: {exc}; the report names the interrupted section", file=sys.stderr)
            return 128 + signal.SIGTERM
        except KeyboardInterrupt:
            print("histostudy reproduce: interrupted by SIGINT; the report names the interrupted section",
                  file=sys.stderr)
            return 128 + signal.SIGINT
        except ValueError as exc:
            print(f"histostudy reproduce: {exc}", file=sys.stderr)
            return 2
        print(f"report: {run.report_md}\n        {run.report_html}")
        return 0
    return 2


def _train(args) -> int:
    import dataclasses

    from .learning import default_cache_dir
    from .learning import TrainingConfig, export, train

    profile = args.profile
    table = profile.training.get(args.task)
    if table is None:
        print(f"histostudy train: profile {profile.name!r} has no [training.{args.task}] table", file=sys.stderr)
        return 2
    try:
        cfg = TrainingConfig.from_table(args.task, table)
        overrides = {k: v for k, v in (("max_minutes", args.max_minutes), ("threads", args.threads),
                                       ("init_weights", args.init_weights)) if v is not None}
        cfg = dataclasses.replace(cfg, **overrides)
    except (ValueError, TypeError) as exc:
        print(f"histostudy train: {exc}", file=sys.stderr)
        return 2
    if args.render_workers < 1:
        print(f"histostudy train: --render-workers must be >= 1, got {args.render_workers}", file=sys.stderr)
        return 2
    if args.render_workers > 1 and cfg.cache:
        import time

        from .learning import HybridFrames, run_frame_sets

        t0 = time.monotonic()
        rendered = sum(HybridFrames(split, profile.seed, config=render, cache_dir=default_cache_dir())
                       .prerender(n, workers=args.render_workers)
                       for render, n_train, n_val in run_frame_sets(cfg)
                       for split, n in (("val", n_val), ("train", n_train)))
        print(f"rendered {rendered} uncached frames in {(time.monotonic() - t0) / 60:.1f} min "
              f"with {args.render_workers} processes")
    run_dir = args.run_dir or default_cache_dir() / "runs" / f"{args.task}-{profile.name}"
    result = train(cfg, run_dir, seed=profile.seed, profile=profile.name, resume=not args.no_resume,
                   progress=not args.no_progress)
    print(f"{args.task}: {result.steps} steps, {result.epochs} epochs in the last stage; stopped: {result.stopped}")
    print(f"best validation: {result.validation}")
    if not args.no_export:
        name = f"{cfg.network['arch']}_{profile.name}"
        manifest = export(result, cfg, name, seed=profile.seed, profile=profile.name, models_dir=args.models_dir)
        print(f"exported {manifest.with_suffix('.safetensors')} (manifest {manifest})")
    return 0


def _pose(args) -> int:
    from .core import atomic_write_json
    from .pose import pose_from_files, pose_record

    try:
        result = pose_from_files(args.frames, args.views, frame_index=args.frame_index,
                                 line_integrals=args.line_integrals, resample=args.resample, seed=args.seed)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"histostudy pose: {exc}", file=sys.stderr)
        return 2
    record = pose_record(result, args.frames)
    atomic_write_json(args.output, record)
    focal = ", ".join(f"{x:.2f}" for x in record["focal_point_mm"])
    verdict = "accepted" if record["accepted"] else "REFUSED: " + "; ".join(record["verdict"]["reasons"])
    print(f"focal point (C-arm frame, mm): {focal}; {verdict}; written to {args.output}")
    return 0 if record["accepted"] else 1


def _report(args) -> int:
    import json
    from pathlib import Path

    from .reporting import build_report

    out = Path(args.output)
    try:
        run = json.loads((out / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        print(f"histostudy report: {out} holds no readable run.json from histostudy reproduce ({exc})",
              file=sys.stderr)
        return 2
    md, html_path = build_report(out, run)
    print(f"report: {md}\n        {html_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
