"""The ``histostudy`` command: ``histostudy reproduce --profile smoke`` and friends."""

from __future__ import annotations

import argparse
import sys

from .profiles import PROFILE_NAMES, load_profile

__all__ = ["main"]


def _profile(value: str):
    try:
        return load_profile(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="histostudy", description=__doc__.strip().splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    rep = sub.add_parser("reproduce", help="run the study notebooks through papermill and write the report")
    rep.add_argument("--profile", type=_profile, default="smoke",
                     help=f"one of {', '.join(PROFILE_NAMES)} or a .toml file (default: smoke)")
    rep.add_argument("--only", nargs="+", metavar="NAME",
                     help="run only these notebooks (stem, number such as 01, or name part)")
    rep.add_argument("--output", default="reports", help="output folder (default: reports)")
    rep.add_argument("--notebooks", default=None, help="notebook folder (default: the repository's notebooks/)")
    rep.add_argument("--no-progress", action="store_true", help="no per-cell progress bar")

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
    if args.command == "reproduce":
        from .pipeline import NotebookFailed, run_study

        try:
            run = run_study(args.profile, args.output, only=args.only, notebooks_dir=args.notebooks,
                            progress=not args.no_progress)
        except NotebookFailed as exc:
            print(f"histostudy reproduce: {exc}", file=sys.stderr)
            return 1
        except ValueError as exc:
            print(f"histostudy reproduce: {exc}", file=sys.stderr)
            return 2
        print(f"report: {run.report_md}\n        {run.report_html}")
        return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
