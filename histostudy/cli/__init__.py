"""The ``histostudy`` command. The study: ``reproduce`` (the notebooks under a profile), ``train``,
``report`` and ``profiles`` (``cli/study.py``). The lab's own data (``cli/lab/``): ``pose`` (frames
-> pose), ``calibrate`` (poses + flange poses -> hand-eye calibration), ``target`` (a target in the
CBCT -> a checked robot move, planned or, with ``--execute``, made), ``listen`` (a DICOM receiver
of live C-arm frames -> poses as they come), ``send`` (DICOM files to a receiver) and
``lab-dataset`` (a generated dataset to try them on). ``--version``, ``-q`` and ``-v`` on every
subcommand; results on stdout, talk on stderr (``cli/console.py``).

Exit status: 0 done, 1 done but refused (a pose verdict, a calibration beyond its bound, a
failing notebook), 2 bad input (named in the message), 130/143 interrupted.
"""

from __future__ import annotations

import argparse
import sys

from . import lab as _lab
from . import study as _study
from .console import common_parent, configure_logging

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from histostudy import __version__

    common = common_parent(__version__)
    version = argparse.ArgumentParser(add_help=False)
    version.add_argument("--version", action="version", version=f"histostudy {__version__}")
    parser = argparse.ArgumentParser(prog="histostudy", parents=[version],
                                     description="Wagner et al. 2023's C-arm guided histotripsy targeting, "
                                                 "reproduced (the study) and run on a lab's own data")
    sub = parser.add_subparsers(dest="command", required=True)
    _study.add_parsers(sub, [common])
    _lab.add_parsers(sub, [common])
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
