"""The lab's subcommands of ``histostudy`` (§II-B to §II-D on the lab's own files and robot), one
module each:

- ``pose FRAMES`` — a biplane pair (DICOM XA, ``.npy``, ``.png``/``.tif``) -> the transducer pose;
- ``calibrate STATION ... --flange-poses F`` — per station a pose record of ``pose`` or a folder of
  its frames, with the flange poses the robot reported -> the hand-eye calibration (Daniilidis);
- ``target --calibration C --target x,y,z [--cbct V] [--robot HOST] [--execute]`` — a checked move
  of the focal point onto a target: planned (a dry run, the default) or, only with ``--execute``
  and a robot, made;
- ``listen --port N --views V`` — a DICOM C-STORE receiver of live C-arm frames -> one pose per
  biplane pair, as JSON lines;
- ``send PEER PORT FILES`` — DICOM files to a C-STORE receiver, as DCMTK's ``storescu``;
- ``lab-dataset FOLDER`` — a generated lab-like dataset to try the others on.

Each writes its result as JSON (atomically: whole or not at all) and prints its summary as one
JSON line on stdout (``cli/console.py``). Exit status 0 done, 1 refused (a verdict, a calibration
beyond its bound, an unreachable target), 2 bad input.
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
    """The lab's subcommands on the ``histostudy`` parser's ``sub``."""
    for add in (add_pose, add_calibrate, add_target, add_listen, add_send, add_lab_dataset):
        add(sub, parents)
