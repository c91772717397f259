"""``histostudy campaign``: a learned stage's training campaign (docs/campaigns.md): ``run`` trains
it some minutes more, from where it stands on this machine or from its committed weights, and
measures it on held-out frames; ``ledger`` prints what every step ran and measured; ``compare``
measures the committed restart weights again beside the baseline, frame by frame."""

from __future__ import annotations

import argparse
import secrets
import sys

from .console import add_command, positive_int

__all__ = ["add_parsers"]


def _minutes(value: str) -> float:
    try:
        minutes = float(value)
    except ValueError:
        minutes = float("nan")
    if not minutes > 0 or minutes == float("inf"):
        raise argparse.ArgumentTypeError(f"minutes must be a finite number > 0, got {value!r}")
    return minutes


def add_parsers(sub, parents) -> None:
    """Add ``histostudy campaign run|ledger|compare``.

    Args:
        sub: the subparsers of the ``histostudy`` parser.
        parents: parent parsers every subcommand takes.
    """
    campaign = add_command(
        sub, "campaign", parents, help="train a learned stage over many runs and machines, keeping a ledger",
        description="A training campaign (data/campaigns/<name>/campaign.toml) goes on run after run: each run "
                    "resumes the campaign's checkpoint in this machine's cache, or restarts from its committed "
                    "float16 weights, trains the minutes given, measures the network on held-out frames of a "
                    "seed drawn afterwards and adds a line to data/campaigns/<name>/ledger.json.",
        example="histostudy campaign run unet-w8-bank --minutes 60 --render-workers 2\n"
                "histostudy campaign ledger unet-w8-bank\n"
                "histostudy campaign compare unet-w8-bank --render-workers 2")
    actions = campaign.add_subparsers(dest="action", required=True, metavar="{run,ledger,compare}")
    run = actions.add_parser("run", parents=parents, help="train the campaign some minutes more and measure it")
    run.add_argument("name", help="the campaign (a folder of data/campaigns)")
    run.add_argument("--minutes", type=_minutes, required=True, help="training minutes of this run (wall)")
    run.add_argument("--eval-seed", type=int, default=None,
                     help="seed of the held-out frames (default: drawn from the operating system after training; "
                          "the ledger records it)")
    run.add_argument("--eval-frames", type=positive_int, default=None,
                     help="held-out frames (default: the campaign's [evaluation] frames)")
    run.add_argument("--render-workers", type=positive_int, default=1,
                     help="processes that render missing frames before training and evaluating (default 1)")
    run.add_argument("--keep", action="store_true",
                     help="also write the network as the campaign's float16 restart weights (to commit), from which "
                          "a machine without this one's cache goes on")
    run.add_argument("--campaigns-dir", default=None, help="folder of the campaigns (default: data/campaigns)")
    run.add_argument("--cache", default=None, help="frame cache and run folder (default: $HISTOSTUDY_CACHE or "
                                                   "~/.cache/histostudy)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(run=_run)
    ledger = actions.add_parser("ledger", parents=parents, help="print the campaign's ledger as a Markdown table")
    ledger.add_argument("name", help="the campaign (a folder of data/campaigns)")
    ledger.add_argument("--campaigns-dir", default=None, help="folder of the campaigns (default: data/campaigns)")
    ledger.set_defaults(run=_ledger)
    compare = actions.add_parser("compare", parents=parents,
                                 help="the committed restart weights beside the baseline on the same held-out frames")
    compare.add_argument("name", help="the campaign (a folder of data/campaigns)")
    which = compare.add_mutually_exclusive_group()
    which.add_argument("--run", type=positive_int, default=None, dest="ledger_run",
                       help="the held-out frames of this ledger run (default: the run that kept the restart weights)")
    which.add_argument("--eval-seed", type=int, default=None, help="held-out frames of this seed instead")
    compare.add_argument("--eval-frames", type=positive_int, default=None,
                         help="frames with --eval-seed (default: the campaign's [evaluation] frames)")
    compare.add_argument("--render-workers", type=positive_int, default=1,
                         help="processes that render missing frames (default 1)")
    compare.add_argument("--campaigns-dir", default=None, help="folder of the campaigns (default: data/campaigns)")
    compare.add_argument("--cache", default=None,
                         help="frame cache (default: $HISTOSTUDY_CACHE or ~/.cache/histostudy)")
    compare.set_defaults(run=_compare)


def _run(args) -> int:
    from histostudy.study.campaign import load_campaign, run_campaign_step

    try:
        spec = load_campaign(args.name, args.campaigns_dir)
        if args.eval_seed is not None and args.eval_seed < 0:
            raise ValueError(f"--eval-seed must be an integer >= 0, got {args.eval_seed}")
    except ValueError as exc:
        print(f"histostudy campaign run: {exc}", file=sys.stderr)
        return 2
    # a seed nobody chose, drawn after the training: the held-out frames cannot have steered it
    eval_seed = secrets.randbelow(2**31) if args.eval_seed is None else args.eval_seed
    try:
        entry = run_campaign_step(spec, args.minutes, eval_seed=eval_seed, cache_dir=args.cache,
                                  eval_frames=args.eval_frames, render_workers=args.render_workers, keep=args.keep,
                                  progress=not args.no_progress and not args.quiet)
    except BlockingIOError as exc:
        print(f"histostudy campaign run: {exc}", file=sys.stderr)
        return 2
    print(f"{spec.name}: run {entry['run']} ({entry['start']}): {entry['wall_minutes']:.1f} min, "
          f"{entry['cpu_hours']:.2f} CPU-hours, steps {entry['steps_before']} -> {entry['steps_after']}; "
          f"stopped: {entry['stopped']}")
    if "paired" in entry:
        print(f"held out ({entry['held_out']['frames']} frames, seed {entry['held_out']['seed']}) against "
              f"{entry['baseline']['weights']}, frame by frame (candidate - baseline):")
        for figure, paired in entry["paired"].items():
            # None: undefined (no frame where both are defined; fewer than 2 differences for the test)
            median, p = paired["median_difference"], paired["p_value"]
            print(f"  {figure}: median difference {'undefined' if median is None else f'{median:+.2f}'}, better "
                  f"on {paired['wins']} of {paired['n']} frames, worse on {paired['losses']}; Wilcoxon p = "
                  f"{'undefined' if p is None else f'{p:.3g}'}")
    print(f"ledger: {spec.ledger_path}")
    return 0


def _ledger(args) -> int:
    from histostudy.study.campaign import ledger_table, load_campaign, read_ledger

    try:
        spec = load_campaign(args.name, args.campaigns_dir)
        runs = read_ledger(spec.ledger_path)
    except ValueError as exc:
        print(f"histostudy campaign ledger: {exc}", file=sys.stderr)
        return 2
    print(f"# {spec.name}: {spec.description}\n")
    if not runs:
        print("no run yet")
        return 0
    print(ledger_table(runs).to_markdown(index=False, floatfmt=".2f"))
    return 0


def _compare(args) -> int:
    import pandas as pd

    from histostudy.study.campaign import compare_restart_weights, load_campaign

    try:
        spec = load_campaign(args.name, args.campaigns_dir)
        if args.eval_seed is not None and args.eval_seed < 0:
            raise ValueError(f"--eval-seed must be an integer >= 0, got {args.eval_seed}")
        out = compare_restart_weights(spec, run=args.ledger_run, eval_seed=args.eval_seed, eval_frames=args.eval_frames,
                                      cache_dir=args.cache, workers=args.render_workers)
    except ValueError as exc:
        print(f"histostudy campaign compare: {exc}", file=sys.stderr)
        return 2
    where = f"run {out['run']}'s" if out["run"] is not None else "the"
    print(f"# {spec.name}: restart weights {out['restart_sha256'][:12]} against {out['baseline_weights']}, on "
          f"{where} {out['frames']} held-out frames (seed {out['seed']})\n")
    rows = []
    for figure, paired in out["paired"].items():
        row = {"figure": figure}
        if "per_class" in out["candidate"]:
            for who in ("candidate", "baseline"):
                m = out[who]["per_class"][figure]
                row[f"{who} P / R / IoU (%)"] = f"{m['precision']:.1f} / {m['recall']:.1f} / {m['iou']:.1f}"
        what = "IoU, points" if "per_class" in out["candidate"] else "deg"
        row.update({f"median difference ({what})": f"{paired['median_difference']:+.2f}", "better / worse / n":
                    f"{paired['wins']} / {paired['losses']} / {paired['n']}", "Wilcoxon p": f"{paired['p_value']:.2g}"})
        rows.append(row)
    print(pd.DataFrame(rows).to_markdown(index=False, disable_numparse=True))
    return 0
