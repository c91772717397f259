"""The lab's subcommands of the command line (§II-B to §II-D on the lab's own files and robot), one
module each: pose (``_pose``), calibrate (``_calibrate``), target (``_target``), listen
(``_listen``), send (``_send``) and lab-dataset (``_dataset``). Each writes its result as JSON
(atomically) and its summary as one JSON line on stdout; exit status 0 done, 1 refused, 2 bad input.
"""

from __future__ import annotations

from ._calibrate import add_calibrate
from ._dataset import add_lab_dataset
from ._listen import add_listen
from ._pose import add_pose
from ._send import add_send
from ._target import add_target

__all__ = ["add_parsers"]


def add_parsers(sub, parents) -> None:
    """Add the lab's subcommands (pose, calibrate, target, listen, send, lab-dataset) to the parser.

    Args:
        sub: the ``histostudy`` parser's sub-parsers (``ArgumentParser.add_subparsers()``).
        parents: the parsers whose options every subcommand shares (``-q``/``-v``, ``--version``).
    """
    for add in (add_pose, add_calibrate, add_target, add_listen, add_send, add_lab_dataset):
        add(sub, parents)
