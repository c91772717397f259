"""Executing a treatment plan on the robot with a journal that resumes where it stopped (paper §II-D).

The robot is commanded in its base frame with the TCP at the transducer's focal point, so
``T_base_tcp`` (4x4, mm) positions the focal point; each plan point (C-arm frame, mm) is mapped into
the base frame by the calibration ``T_base_carm`` (§II-C) and reached by a linear move, the
transducer's orientation ``R_base_tcp`` kept throughout; then the point's fixed number of pulses is
fired.

Execution keeps a journal (JSON, rewritten atomically after every treated point with
:func:`histostudy.core.io.atomic_write_text`): a treatment interrupted by a robot fault resumes from
the journal — on a fresh connection or a fresh robot — without treating a point twice or skipping
one. A point counts as treated once its journal entry is on disk.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from histostudy.core import atomic_write_json, atomic_write_text, to_jsonable
from histostudy.geometry import check_rigid, check_rotation, make_transform, transform_points
from .plan import TreatmentPlan

__all__ = [
    "JOURNAL_FORMAT",
    "TreatmentRun",
    "execute_treatment",
    "load_journal",
]

JOURNAL_FORMAT = "histostudy.treatment_journal"
JOURNAL_VERSION = 1


@dataclass(frozen=True, eq=False)
class TreatmentRun:
    """What the journal holds about a treatment: per treated point (in plan order) the commanded
    and reached ``T_base_tcp`` (n, 4, 4) mm, the pulses delivered, and whether the plan is done.
    ``resumed_at``: the first point treated by the run that returned this (0 for a fresh start)."""

    journal_path: Path
    n_planned: int
    commanded_T_base_tcp: np.ndarray
    reached_T_base_tcp: np.ndarray
    pulses: np.ndarray
    indices: np.ndarray
    completed: bool
    resumed_at: int

    @property
    def n_treated(self) -> int:
        return len(self.indices)

    @classmethod
    def load(cls, journal_path: str | os.PathLike) -> "TreatmentRun":
        """The run recorded in a journal (``resumed_at`` = the number of points it holds)."""
        path = Path(journal_path)
        journal = load_journal(path)
        return _run_from_journal(path, journal, len(journal["points"]))


def _journal_header(plan: TreatmentPlan, T_base_carm: np.ndarray, R_base_tcp: np.ndarray, T_flange_tcp) -> dict:
    return {
        "format": JOURNAL_FORMAT,
        "version": JOURNAL_VERSION,
        "plan_fingerprint": plan.fingerprint(),
        "plan": plan.to_dict(),
        "T_base_carm": T_base_carm,
        "R_base_tcp": R_base_tcp,
        "T_flange_tcp": T_flange_tcp,
        "completed": False,
        "points": [],
    }


def load_journal(path: str | os.PathLike) -> dict:
    """Read and check a treatment journal (format, version, entries in plan order); returns the dict."""
    path = Path(path)
    try:
        journal = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"journal {path} is not valid JSON ({exc}); it was not written by execute_treatment") from exc
    if not isinstance(journal, dict) or journal.get("format") != JOURNAL_FORMAT:
        raise ValueError(f"journal {path} is not a treatment journal (format must be {JOURNAL_FORMAT!r})")
    if journal.get("version") != JOURNAL_VERSION:
        raise ValueError(f"journal {path} has version {journal.get('version')!r}; this code reads version {JOURNAL_VERSION}")
    indices = [p["index"] for p in journal["points"]]
    if indices != list(range(len(indices))):
        raise ValueError(f"journal {path} holds points {indices[:10]}..., not the plan's first points in order")
    return journal


def _run_from_journal(path: Path, journal: dict, resumed_at: int) -> TreatmentRun:
    pts = journal["points"]
    return TreatmentRun(
        journal_path=path,
        n_planned=len(journal["plan"]["points_mm"]),
        commanded_T_base_tcp=np.array([p["commanded_T_base_tcp"] for p in pts], dtype=np.float64).reshape(-1, 4, 4),
        reached_T_base_tcp=np.array([p["reached_T_base_tcp"] for p in pts], dtype=np.float64).reshape(-1, 4, 4),
        pulses=np.array([p["pulses"] for p in pts], dtype=int),
        indices=np.array([p["index"] for p in pts], dtype=int),
        completed=bool(journal["completed"]),
        resumed_at=resumed_at,
    )


def execute_treatment(
    robot,
    plan: TreatmentPlan,
    T_base_carm,
    R_base_tcp,
    journal_path: str | os.PathLike,
    *,
    T_flange_tcp=None,
    speed_mm_s: float = 20.0,
    acceleration_mm_s2: float = 200.0,
    deliver: Callable[[int, int], None] | None = None,
) -> TreatmentRun:
    """Move the focal point through ``plan`` on ``robot`` and treat each point; journal every point.

    ``T_base_carm``: the calibration (C-arm frame into the robot base frame). ``R_base_tcp``: the
    transducer orientation the targeting chose (3x3, base frame), kept for every point: point ``p``
    (world mm) is commanded as ``T_base_tcp = [R_base_tcp | T_base_carm @ p]``, a linear move at
    ``speed_mm_s`` / ``acceleration_mm_s2``. ``T_flange_tcp``: if given, set on the robot first
    (the focal point in the flange frame) and recorded; a resume must use the same.
    ``deliver(index, pulses)``: fires the plan's pulses at the reached point (the therapy
    sub-system; the simulation has nothing to fire, so the default does nothing).

    Journal (``journal_path``, JSON, rewritten atomically after each point): the plan and its
    fingerprint, the calibration, and per treated point its index, the world point, the commanded
    and the reached ``T_base_tcp`` and the pulses. If the journal exists, its plan and calibration
    must match and execution resumes after its last point (a completed journal returns at once).
    A :class:`~histostudy.robot.RobotError` propagates unchanged, with a note saying how far the
    journal got; running again with the same journal resumes. A point counts as treated once its
    entry is on disk: a fault inside ``deliver``, or a crash between its last pulse and the write,
    leaves the point out of the journal and a resume fires it again (the only way a point is
    treated twice). A resumed run moves straight from wherever the arm is to the next point; the
    robot's workspace checks apply, an approach path is the caller's.
    """
    if not isinstance(plan, TreatmentPlan):
        raise TypeError(f"plan must be a TreatmentPlan, got {type(plan).__name__}")
    T_bc = check_rigid(T_base_carm, "T_base_carm")
    R = check_rotation(R_base_tcp, "R_base_tcp")
    T_ft = None if T_flange_tcp is None else check_rigid(T_flange_tcp, "T_flange_tcp")
    if deliver is not None and not callable(deliver):
        raise TypeError(f"deliver must be callable(index, pulses) or None, got {type(deliver).__name__}")
    if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
        raise ValueError(f"speed_mm_s must be finite and > 0, got {speed_mm_s!r}")
    if not (math.isfinite(acceleration_mm_s2) and acceleration_mm_s2 > 0):
        raise ValueError(f"acceleration_mm_s2 must be finite and > 0, got {acceleration_mm_s2!r}")
    path = Path(journal_path)
    header = to_jsonable(_journal_header(plan, T_bc, R, T_ft))
    if path.exists():
        journal = load_journal(path)
        if journal["plan_fingerprint"] != header["plan_fingerprint"]:
            raise ValueError(f"journal {path} belongs to another plan (fingerprint differs); refusing to resume it with this plan")
        for key in ("T_base_carm", "R_base_tcp", "T_flange_tcp"):
            a, b = journal[key], header[key]
            if (a is None) != (b is None) or (a is not None and not np.allclose(a, b, rtol=0, atol=1e-9)):
                raise ValueError(f"journal {path} was written with another {key} ({a!r}); got {b!r}: refusing to resume")
    else:
        journal = header
        atomic_write_json(path, journal)
    start = len(journal["points"])
    if journal["completed"]:
        return _run_from_journal(path, journal, start)

    # The journal is rewritten whole after every point; its entries are serialised once and the
    # file assembled from the cached texts, so a write costs O(file size), not O(entries) of
    # Python-object conversion (a 1000-point plan would otherwise spend minutes in json.dumps).
    head = {k: v for k, v in journal.items() if k not in ("completed", "points")}
    head_text = json.dumps(head, separators=(",", ":"))[:-1]
    entries = [json.dumps(e, separators=(",", ":")) for e in journal["points"]]

    def write(completed: bool) -> None:
        text = f'{head_text},"completed":{"true" if completed else "false"},"points":[\n' + ",\n".join(entries) + "\n]}\n"
        atomic_write_text(path, text)

    if T_ft is not None:
        robot.set_tcp(T_ft)
    targets = transform_points(T_bc, plan.points_mm)
    for i in range(start, len(plan)):
        commanded = make_transform(R, targets[i])
        try:
            reached = np.asarray(robot.move_linear(commanded, speed_mm_s, acceleration_mm_s2), dtype=np.float64)
            if deliver is not None:
                deliver(i, plan.pulses_per_point)
        except Exception as exc:
            exc.add_note(
                f"treatment interrupted at point {i} of {len(plan)}: the journal {path} holds points 0..{i - 1}; "
                "run execute_treatment again with the same journal to resume"
            )
            raise
        entries.append(
            json.dumps(
                {
                    "index": i,
                    "point_carm_mm": plan.points_mm[i].tolist(),
                    "commanded_T_base_tcp": commanded.tolist(),
                    "reached_T_base_tcp": reached.tolist(),
                    "pulses": plan.pulses_per_point,
                },
                separators=(",", ":"),
            )
        )
        write(i == len(plan) - 1)
    if len(plan) == start:  # nothing left (an empty remainder): mark done
        write(True)
    return _run_from_journal(path, load_journal(path), start)
