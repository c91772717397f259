"""The study's subcommands of ``histostudy``: ``reproduce --profile smoke`` (the notebooks through
papermill, then the report), ``train segmentation|orientation|segmentation_tracking[_fine]``,
``calibrate-int8`` (a U-Net's int8 network for CPUs without bfloat16), ``report`` (rebuilt from a
reproduce folder), ``publish`` (a finished run into docs/results/<profile>) and ``profiles``."""

from __future__ import annotations

import argparse
import signal
import sys

from histostudy.reporting import PROFILE_NAMES, load_profile

from .console import add_command, positive_int

#: The ``[training.<table>]`` tables ``histostudy train`` runs (histostudy.learning.TRAINING_TABLES).
TRAINING_TABLE_NAMES = ("segmentation", "orientation", "segmentation_tracking", "segmentation_tracking_fine",
                        "segmentation_gpu", "orientation_gpu")

__all__ = ["add_parsers"]


def _profile(value: str):
    try:
        return load_profile(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


_positive_int = positive_int  # the one check of a count argument (cli/console.py)


def add_parsers(sub, parents) -> None:
    """Add the study's subcommands (reproduce, publish, train, calibrate-int8, report, profiles).

    Args:
        sub: the subparsers of the ``histostudy`` parser.
        parents: parent parsers every subcommand takes (:func:`~.console.common_parent`).
    """
    rep = add_command(
        sub, "reproduce", parents, help="run the study notebooks through papermill and write the report",
        description="Run the study's notebooks (notebooks/NN_*.ipynb) in order through papermill under a profile, "
                    "then write the report (REPORT.md, report.html) beside each notebook's results, tables and "
                    "figures. Exit status 1 when a notebook fails (named, with its cell).",
        example="histostudy reproduce --profile smoke --output reports\n"
                "histostudy reproduce --profile standard --only 04 05 --workers 2")
    rep.add_argument("--profile", type=_profile, default="smoke",
                     help=f"one of {', '.join(PROFILE_NAMES)} or a .toml file (default: smoke)")
    rep.add_argument("--only", nargs="+", metavar="NAME",
                     help="run only these notebooks (stem, number such as 01, or name part)")
    rep.add_argument("--output", default="reports", help="output folder (default: reports)")
    rep.add_argument("--notebooks", default=None,
                     help="notebook folder (default: a checkout's notebooks/, else the ones packaged with histostudy)")
    rep.add_argument("--no-progress", action="store_true", help="no per-cell progress bar")
    rep.add_argument("--workers", type=_positive_int, default=1, metavar="N",
                     help="notebooks run at once, each in its own kernel (default: 1; the numbers do not depend on it)")
    rep.add_argument("--sweep-workers", type=_positive_int, default=None, metavar="N",
                     help="processes each notebook's Monte-Carlo sweeps run in, where HISTOSTUDY_SCHEDULER is unset "
                          "(default: the cores left to each notebook, cores // --workers; 1: in the kernel; the "
                          "numbers do not depend on it)")
    rep.add_argument("--force", action="store_true",
                     help="run every notebook again, even a section finished with the same content key (notebook, "
                          "parameters, code, weights, libraries), which is otherwise kept")
    rep.set_defaults(run=_reproduce)

    pub = add_command(
        sub, "publish", parents,
        help="publish a finished reproduce folder into the repository (docs/results/<profile>)",
        description="Copy a finished `histostudy reproduce` run's report, run record, sections' results, tables and "
                    "figures, and its executed notebooks (the machine's paths taken out), into a folder of the "
                    "repository, replaced whole, and put its headline table into the README between its markers.",
        example="histostudy publish reports-standard --to docs/results/standard --readme README.md")
    pub.add_argument("run_dir", metavar="RUN_DIR", help="the folder histostudy reproduce wrote")
    pub.add_argument("--to", required=True, metavar="DIR", help="where to publish (replaced whole)")
    pub.add_argument("--readme", default=None, metavar="FILE",
                     help="a README whose block between <!-- published-headline:begin/end --> gets the headline")
    pub.add_argument("--partial", action="store_true",
                     help="publish although some notebooks did not run (the report names them)")
    pub.set_defaults(run=_publish)

    _add_train_parser(sub, parents)

    cal = add_command(
        sub, "calibrate-int8", parents,
        help="calibrate a U-Net's int8 network (UNetRunner precision 'int8', an option of the tracker on a CPU "
             "without bfloat16) on validation frames and store it beside its weights",
        description="Calibrate the activation ranges of a U-Net's int8 network on validation frames and store them "
                    "beside its weights (with their SHA-256), where UNetRunner(precision='int8') finds them.",
        example="histostudy calibrate-int8 --model unet_standard --frames 24")
    cal.add_argument("--model", default="unet_standard", help="U-Net weights in data/models (default: unet_standard)")
    cal.add_argument("--frames", type=_positive_int, default=24,
                     help="validation frames of the profile's seed to calibrate on (default: 24)")
    cal.add_argument("--profile", type=_profile, default="standard",
                     help="the profile whose seed draws the frames (default: standard)")
    cal.add_argument("--output", default=None,
                     help="where the calibration goes (default: data/models/<model>.int8.json, where UNetRunner "
                          "finds it)")
    cal.set_defaults(run=_calibrate_int8)

    rebuild = add_command(
        sub, "report", parents, help="rebuild REPORT.md and report.html from a reproduce output folder",
        description="Rebuild REPORT.md and report.html from the files a `histostudy reproduce` run wrote "
                    "(run.json and each section's results), e.g. after a run on another machine.",
        example="histostudy report --output reports")
    rebuild.add_argument("--output", default="reports", help="the folder reproduce wrote (default: reports)")
    rebuild.set_defaults(run=_report)

    prof = add_command(sub, "profiles", parents, help="list the built-in profiles",
                       description="List the built-in profiles (smoke, standard, paper): seed and what each is for.",
                       example="histostudy profiles")
    prof.set_defaults(run=_profiles)


def _add_train_parser(sub, parents) -> None:
    """Add ``histostudy train`` (a learned stage trained as a profile's ``[training.<task>]`` says).

    Args:
        sub: the subparsers of the ``histostudy`` parser.
        parents: parent parsers every subcommand takes.
    """
    tr = add_command(
        sub, "train", parents, help="train a learned stage (U-Net or VGG19) on hybrid images and export its weights",
        description="Train a learned stage on hybrid frames as the profile's [training.<task>] table says, resuming "
                    "an interrupted run from its folder, and export the best weights with their manifest to "
                    "data/models (docs/training.md).",
        example="histostudy train segmentation --profile standard\n"
                "histostudy train orientation --profile smoke --run-dir /tmp/run --no-export")
    tr.add_argument("task", choices=tuple(TRAINING_TABLE_NAMES),
                    help="the profile's [training.<task>] table: segmentation (U-Net), orientation (VGG19) or "
                         "segmentation_tracking (the U-Net of Tracker(fast=True) at input scale 0.25, exported as "
                         "unet_tracking) or segmentation_tracking_fine (the U-Net that reads 0.5 and runs its levels "
                         "at 0.25, exported as unet_tracking_fine) or segmentation_gpu / orientation_gpu (the study's "
                         "networks as the prepared GPU run trains them, scripts/gpu_training_run.py)")
    tr.add_argument("--profile", type=_profile, default="standard",
                    help=f"one of {', '.join(PROFILE_NAMES)} or a .toml file with [training.<task>] "
                         "(default: standard)")
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
    tr.add_argument("--render-only", action="store_true",
                    help="render the uncached frames (in --render-workers processes) and stop without training: on a "
                         "leased GPU, render first, then give the training the time that is left (--max-minutes)")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.set_defaults(run=_train)


def _profiles(args) -> int:
    for name in PROFILE_NAMES:
        p = load_profile(name)
        print(f"{p.name:9s} seed {p.seed}  {p.description}")
    return 0


def _reproduce(args) -> int:
    from histostudy.reporting import NotebookFailed, StudyInterrupted, run_study

    try:
        run = run_study(args.profile, args.output, only=args.only, notebooks_dir=args.notebooks,
                        progress=not args.no_progress and not args.quiet and args.workers == 1, workers=args.workers,
                        sweep_workers=args.sweep_workers, force=args.force)
    except NotebookFailed as exc:
        print(f"histostudy reproduce: {exc}", file=sys.stderr)
        return 1
    except StudyInterrupted as exc:
        print(f"histostudy reproduce: {exc}; the report names the interrupted section", file=sys.stderr)
        return 128 + signal.Signals[exc.signal_name]
    except KeyboardInterrupt:
        print("histostudy reproduce: interrupted by SIGINT; the report names the interrupted section",
              file=sys.stderr)
        return 128 + signal.SIGINT
    except ValueError as exc:
        message = str(exc)
        if args.notebooks is not None:
            message = message.replace("notebooks_dir", "--notebooks", 1)
        print(f"histostudy reproduce: {message}", file=sys.stderr)
        return 2
    print(f"report: {run.report_md}\n        {run.report_html}")
    return 0


def _publish(args) -> int:
    import os
    from pathlib import Path

    from histostudy.reporting import publish_run, replace_readme_headline

    try:
        report = publish_run(args.run_dir, args.to, allow_partial=args.partial)
        if args.readme:
            prefix = Path(os.path.relpath(report, Path(args.readme).resolve().parent)).as_posix()
            replace_readme_headline(args.readme, report.parent, prefix)
    except (ValueError, OSError) as exc:
        print(f"histostudy publish: {exc}", file=sys.stderr)
        return 2
    print(f"published: {report}")
    return 0


def _train(args) -> int:
    import dataclasses

    from histostudy.learning import TRAINING_TABLES, TrainingConfig, default_cache_dir, export, export_name, train

    profile = args.profile
    table = profile.training.get(args.task)
    if table is None:
        print(f"histostudy train: profile {profile.name!r} has no [training.{args.task}] table", file=sys.stderr)
        return 2
    try:
        cfg = TrainingConfig.from_table(TRAINING_TABLES[args.task][0], table)
        overrides = {k: v for k, v in (("max_minutes", args.max_minutes), ("threads", args.threads),
                                       ("init_weights", args.init_weights)) if v is not None}
        cfg = dataclasses.replace(cfg, **overrides)
    except (ValueError, TypeError) as exc:
        print(f"histostudy train: {exc}", file=sys.stderr)
        return 2
    if args.render_workers < 1:
        print(f"histostudy train: --render-workers must be >= 1, got {args.render_workers}", file=sys.stderr)
        return 2
    if args.render_only and not cfg.cache:
        print(f"histostudy train: --render-only renders into the frame cache, but [training.{args.task}] has "
              f"cache = false", file=sys.stderr)
        return 2
    if (args.render_workers > 1 or args.render_only) and cfg.cache:
        import time

        from histostudy.learning import prerender_run

        t0 = time.monotonic()
        rendered = prerender_run(cfg, profile.seed, cache_dir=default_cache_dir(), workers=args.render_workers)
        print(f"rendered {rendered} uncached frames in {(time.monotonic() - t0) / 60:.1f} min "
              f"with {args.render_workers} processes")
        if args.render_only:
            return 0
    run_dir = args.run_dir or default_cache_dir() / "runs" / f"{args.task}-{profile.name}"
    result = train(cfg, run_dir, seed=profile.seed, profile=profile.name, resume=not args.no_resume,
                   progress=not args.no_progress and not args.quiet)
    print(f"{args.task}: {result.steps} steps, {result.epochs} epochs in the last stage; stopped: {result.stopped}")
    print(f"best validation: {result.validation}")
    if not args.no_export:
        name = export_name(args.task, cfg.network["arch"], profile.name)
        manifest = export(result, cfg, name, seed=profile.seed, profile=profile.name, models_dir=args.models_dir)
        print(f"exported {manifest.with_suffix('.safetensors')} (manifest {manifest})")
    return 0


def _calibrate_int8(args) -> int:
    import time

    from histostudy.learning import MODELS_DIR, HybridFrames, UNetRunner, default_cache_dir
    from histostudy.learning.inference import (
        calibrate_int8,
        int8_available,
        int8_calibration_path,
        save_int8_calibration,
    )

    if not int8_available():
        print("histostudy calibrate-int8: this torch has no int8 (oneDNN) kernels", file=sys.stderr)
        return 2
    try:
        segmenter = UNetRunner.load(MODELS_DIR / f"{args.model}.safetensors")
    except (OSError, ValueError) as exc:
        print(f"histostudy calibrate-int8: --model {args.model!r}: {exc}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    frames = HybridFrames("val", args.profile.seed, cache_dir=default_cache_dir())
    calibration = calibrate_int8(segmenter, [frames.frame(i) for i in range(args.frames)])
    path = save_int8_calibration(calibration, args.output or int8_calibration_path(segmenter))
    print(f"calibrated {args.model} on {args.frames} validation frames of seed {args.profile.seed} in "
          f"{time.monotonic() - t0:.0f} s: {len(calibration['activation_qparams'])} activations -> {path}")
    return 0


def _report(args) -> int:
    import json
    from pathlib import Path

    from histostudy.reporting import build_report

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
