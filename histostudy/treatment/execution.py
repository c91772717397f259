"""Executing a treatment plan on the robot with a journal that never fires a point twice (§II-D): each point
(C-arm mm) mapped into the base frame by ``T_base_carm`` and reached by a linear move; interrupted runs
resume (docs/robot.md)."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from histostudy.geometry import check_rigid, check_rotation, make_transform, transform_points

from .journal import TreatmentJournal
from .plan import TreatmentPlan

__all__ = [
    "UNCERTAIN_POLICIES",
    "TreatmentRun",
    "UncertainPointError",
    "execute_treatment",
    "load_journal",
]

#: How :func:`execute_treatment` settles a point whose pulses may have been fired (an intent and no
#: done): ``"refuse"`` (raise before the robot moves: the default, which never fires a point twice),
#: ``"refire"`` (fire it again, recorded as possibly fired twice), ``"skip"`` (count it finished
#: without firing it again, recorded as skipped with 0 pulses from the resumed run). Which is right
#: depends on what the therapy system's own log says about the point.
UNCERTAIN_POLICIES = ("refuse", "refire", "skip")


class UncertainPointError(RuntimeError):
    """A resumed treatment found a point whose pulses may or may not have been fired; ``index``."""

    def __init__(self, message: str, index: int):
        super().__init__(message)
        self.index = index


@dataclass(frozen=True, eq=False)
class TreatmentRun:
    """What the journal holds about a treatment: per finished point (in plan order) the commanded
    and reached ``T_base_tcp`` (n, 4, 4) mm, the pulses delivered, and whether the plan is done.
    ``resumed_at``: the first point treated by the run that returned this (0 for a fresh start).
    ``refired`` / ``skipped``: the uncertain points settled by re-firing (possibly fired twice) or
    by skipping (possibly never fired); ``uncertain``: a point still unsettled, or None."""

    journal_path: Path
    n_planned: int
    commanded_T_base_tcp: np.ndarray
    reached_T_base_tcp: np.ndarray
    pulses: np.ndarray
    indices: np.ndarray
    completed: bool
    resumed_at: int
    refired: tuple = ()
    skipped: tuple = ()
    uncertain: int | None = None

    @property
    def n_treated(self) -> int:
        return len(self.indices)

    @classmethod
    def load(cls, journal_path: str | os.PathLike) -> TreatmentRun:
        """The run recorded in a journal (``resumed_at`` = the number of points it holds)."""
        with TreatmentJournal.open_for_reading(journal_path) as journal:
            return _run_from_journal(journal, len(journal.finished))


def load_journal(path: str | os.PathLike) -> dict:
    """Read and check a treatment journal (SQLite, or a version-1 JSON one); returns a dict with
    ``format``, ``version``, ``plan_fingerprint``, ``plan``, the calibration (``T_base_carm``,
    ``R_base_tcp``, ``T_flange_tcp``), ``completed``, ``points`` (the finished ones in order, each
    with ``index``, ``point_carm_mm``, ``commanded_T_base_tcp``, ``reached_T_base_tcp``, ``pulses``,
    ``resolution``) and ``uncertain`` (an unsettled point's index, or None). Raises
    :class:`~.journal.JournalError` for a journal that fails its checks."""

    with TreatmentJournal.open_for_reading(path) as journal:
        meta = journal.meta
        out = {"format": meta["format"], "version": int(meta["version"]), "plan_fingerprint": meta["plan_fingerprint"],
               "plan": json.loads(meta["plan"])}
        out.update({k: json.loads(meta[k]) for k in ("T_base_carm", "R_base_tcp", "T_flange_tcp")})
        out["completed"] = journal.completed
        out["points"] = [{"index": i, "point_carm_mm": p, "commanded_T_base_tcp": c, "reached_T_base_tcp": r,
                          "pulses": n, "resolution": res} for i, p, c, r, n, res in journal.rows()]
        out["uncertain"] = journal.uncertain
        return out


def _run_from_journal(journal: TreatmentJournal, resumed_at: int) -> TreatmentRun:
    rows = journal.rows()
    return TreatmentRun(
        journal_path=journal.path,
        n_planned=journal.n_planned,
        commanded_T_base_tcp=np.array([r[2] for r in rows], dtype=np.float64).reshape(-1, 4, 4),
        reached_T_base_tcp=np.array([r[3] for r in rows], dtype=np.float64).reshape(-1, 4, 4),
        pulses=np.array([r[4] for r in rows], dtype=int),
        indices=np.array([r[0] for r in rows], dtype=int),
        completed=journal.completed,
        resumed_at=resumed_at,
        refired=tuple(r[0] for r in rows if r[5] == "refired"),
        skipped=tuple(r[0] for r in rows if r[5] == "skipped"),
        uncertain=journal.uncertain,
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
    on_uncertain: str | Callable[[int], str] = "refuse",
) -> TreatmentRun:
    """Move the focal point through a plan on the robot and treat each point, journaling every point
    (§II-D); resumable, never firing a point twice unless told.

    Point ``p`` (world mm) is commanded as ``T_base_tcp = [R_base_tcp | T_base_carm @ p]``, a linear
    move. Per point: move, commit the intent, fire, commit the done. A resumed run moves straight from
    wherever the arm is to the next point; the robot's workspace checks apply, an approach path is
    the caller's. The journal: docs/robot.md.

    Args:
        robot: a :class:`~histostudy.robot.Robot` (mm, base frame).
        plan: the :class:`~.plan.TreatmentPlan` (world mm).
        T_base_carm: (4, 4) rigid calibration, C-arm -> robot base, mm.
        R_base_tcp: (3, 3) rotation, the transducer orientation the targeting chose, base frame, kept
            for every point.
        journal_path: the SQLite journal (:mod:`.journal`): created for this plan and calibration, or
            resumed (its plan and calibration must match; a completed journal returns at once; a
            version-1 JSON journal is migrated).
        T_flange_tcp: (4, 4) rigid, the focal point in the flange frame, mm; if given, set on the
            robot first and recorded (a resume must use the same).
        speed_mm_s: the linear moves' speed, mm/s, > 0.
        acceleration_mm_s2: their acceleration, mm/s^2, > 0.
        deliver: ``deliver(index, pulses)`` fires the plan's pulses at the reached point (the therapy
            sub-system); None fires nothing (the simulation).
        on_uncertain: how to settle a point left with an intent and no done: one of
            :data:`UNCERTAIN_POLICIES`, or a callable ``index -> policy`` that asks someone.

    Returns:
        The :class:`TreatmentRun`, listing the points re-fired or skipped.

    Raises:
        TypeError: ``plan`` is not a TreatmentPlan, or ``deliver`` is not callable.
        ValueError: a pose not rigid, a speed, acceleration or policy out of range.
        JournalError: the journal belongs to another plan or calibration, or cannot be trusted.
        JournalLockedError: another process holds the journal (before the robot moves).
        UncertainPointError: with ``"refuse"`` (the default), a point may have been fired (before
            the robot moves).
        RobotError: from the robot, unchanged, with a note saying how far the journal got; running
            again with the same journal resumes.
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
    if not callable(on_uncertain) and on_uncertain not in UNCERTAIN_POLICIES:
        raise ValueError(f"on_uncertain must be one of {UNCERTAIN_POLICIES} or a callable(index) -> policy, "
                         f"got {on_uncertain!r}")
    path = Path(journal_path)
    calibration = {"T_base_carm": T_bc, "R_base_tcp": R, "T_flange_tcp": T_ft}
    targets = transform_points(T_bc, plan.points_mm)
    with TreatmentJournal.open_for_run(path, plan, calibration) as journal:
        start = len(journal.finished)
        refire = None
        if journal.uncertain is not None:
            refire = _settle(journal, on_uncertain, plan)
        if journal.completed:
            return _run_from_journal(journal, start)
        if T_ft is not None:
            robot.set_tcp(T_ft)
        for i in range(len(journal.finished), len(plan)):
            commanded = make_transform(R, targets[i])
            try:
                reached = np.asarray(robot.move_linear(commanded, speed_mm_s, acceleration_mm_s2), dtype=np.float64)
                journal.record_intent(i, plan.points_mm[i], commanded, reached)
                if deliver is not None:
                    deliver(i, plan.pulses_per_point)
            except Exception as exc:
                uncertain = journal.uncertain == i
                exc.add_note(
                    f"treatment interrupted at point {i} of {len(plan)}: the journal {path} holds points 0..{i - 1}"
                    + (f"; point {i}'s pulses may have been fired (its intent is recorded): a resume asks how to "
                       "settle it (on_uncertain)" if uncertain else "")
                    + "; run execute_treatment again with the same journal to resume")
                raise
            journal.record_done(i, plan.pulses_per_point, "refired" if i == refire else None)
        return _run_from_journal(journal, start)


def _settle(journal: TreatmentJournal, on_uncertain, plan: TreatmentPlan) -> int | None:
    """Apply the policy to the journal's uncertain point; returns its index if it is to be re-fired."""
    index = journal.uncertain
    if index is None:
        return None
    policy = on_uncertain(index) if callable(on_uncertain) else on_uncertain
    if policy not in UNCERTAIN_POLICIES:
        raise ValueError(f"on_uncertain({index}) must return one of {UNCERTAIN_POLICIES}, got {policy!r}")
    if policy == "refuse":
        raise UncertainPointError(
            f"journal {journal.path}: point {index} of {len(plan)} was reached and its firing began, but its end "
            "was never recorded, so its pulses may or may not have been delivered. Check the therapy system's "
            "log, then resume with on_uncertain='refire' (fire it again) or on_uncertain='skip' (count it done "
            "with 0 pulses); the journal records the choice. Nothing was moved or fired.", index)
    if policy == "skip":
        journal.record_done(index, 0, "skipped")
        return None
    return index
