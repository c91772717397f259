"""The command line, `histostudy`: the study's subcommands (``study``: reproduce, train, report, publish,
profiles; ``campaign``: the learned stages' training campaigns) and the lab's (``lab``: pose, calibrate,
target, listen, send, lab-dataset), with what they share with the terminal (``console``: results on
stdout, talk on stderr). Exit status: 0 done, 1 done but refused, 2 bad input, 130/143 interrupted
(README.md, "Command line")."""

from __future__ import annotations

import argparse
import sys

from . import campaign as _campaign
from . import lab as _lab
from . import study as _study
from .console import common_parent, configure_logging

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``histostudy`` parser with every subcommand; each sets ``run``, the function that runs it.

    Returns:
        The parser; ``build_parser().parse_args(argv).run(args)`` runs a command (:func:`main`).
    """
    from histostudy import __version__

    common = common_parent(__version__)
    version = argparse.ArgumentParser(add_help=False)
    version.add_argument("--version", action="version", version=f"histostudy {__version__}")
    parser = argparse.ArgumentParser(prog="histostudy", parents=[version],
                                     description="Wagner et al. 2023's C-arm guided histotripsy targeting, "
                                                 "reproduced (the study) and run on a lab's own data")
    sub = parser.add_subparsers(dest="command", required=True)
    _study.add_parsers(sub, [common])
    _campaign.add_parsers(sub, [common])
    _lab.add_parsers(sub, [common])
    return parser


def main(argv=None) -> int:
    """Run one ``histostudy`` command: parse ``argv``, route the loggers to stderr at the level ``-q`` /
    ``-v`` ask for, and run the subcommand.

    Args:
        argv: the arguments after ``histostudy`` (``["reproduce", "--profile", "smoke"]``); None reads
            ``sys.argv[1:]``.

    Returns:
        The exit status: 0 done, 1 done but refused (a pose verdict, a calibration beyond its bound, a
        failing notebook), 2 bad input (named in the message), 130/143 interrupted (SIGINT/SIGTERM).

    Raises:
        SystemExit: argparse's, for ``--help``, ``--version`` (status 0) or unparsable arguments (2).
    """
    args = build_parser().parse_args(argv)
    configure_logging(args)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
