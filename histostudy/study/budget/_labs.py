"""Many labs (§III, §IV): the lab error model drawn for several labs (lab 0 the notebook's, lab
``k`` from :func:`lab_seed`), each lab's experiments run with all its sources on, frames shared
between labs whose frames are alike. C-arm frame, mm (docs/error-budget.md, "Many labs").
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Sequence

import numpy as np
import pandas as pd

from histostudy.core import SweepExecutor, run_sweep
from histostudy.imaging import View
from histostudy.transducer import TransducerModel

from ._run import BudgetSetup, _pose_task, _targeting_task
from ._shared import shared_work
from ._sources import LabDraw, LabErrorModel, draw_lab

__all__ = ["LAB_MAGNITUDES", "draw_labs", "frames_alike", "lab_magnitudes", "lab_seed",
           "labs_records", "run_labs"]

#: The spawn-key element under which labs ``k >= 1`` draw (distinct from every source's stream index).
_LABS_KEY = 0x4C414253

#: The systematic sources with a per-lab magnitude (:func:`lab_magnitudes`) and what it measures (mm).
LAB_MAGNITUDES = {
    "manufacturing": "distance of the lab's transducer's focal point from the digital model's",
    "bubble_offset": "length of the bubble cloud's offset from the physical focal point",
    "projection": "shift of the isocentre's projection, calibrated against true view, at the detector, mean of "
                  "the planes",
    "gantry_sag": "displacement of each plane's source by the sag, mean of the planes",
}


def lab_seed(seed, index: int) -> np.random.SeedSequence:
    """Lab ``index``'s seed: ``seed`` itself (an int or a ``SeedSequence``) for lab 0, else the child
    of ``seed`` at spawn key ``(..., LABS, index)``, apart from every stream lab 0 draws from."""
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"index must be an integer >= 0, got {index!r}")
    if index == 0:
        return seq
    return np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, _LABS_KEY, int(index)),
                                  pool_size=seq.pool_size)


def draw_labs(model: LabErrorModel, seed, n_labs: int, *, physical: TransducerModel, views,
              physical_seed: np.random.SeedSequence | int | None = None) -> list[LabDraw]:
    """``n_labs`` labs of ``model``: lab 0 is :func:`~histostudy.study.budget.draw_lab` of ``seed``
    (the notebook's single lab, number for number); lab ``k`` draws everything, its transducer
    included, from :func:`lab_seed` ``(seed, k)``.

    Args:
        model: the lab error model.
        seed: the lab seed (an int or a SeedSequence).
        n_labs: the labs (>= 1).
        physical: the study's physical transducer (where ``manufacturing`` is off; lab 0's spec).
        views: the study's calibrated views.
        physical_seed: the seed the study drew its transducer from (lab 0's quadrants).

    Returns:
        The :class:`~histostudy.study.budget._sources.LabDraw` of each lab.

    Raises:
        ValueError: ``n_labs`` not an integer >= 1.
    """
    if isinstance(n_labs, bool) or not isinstance(n_labs, (int, np.integer)) or n_labs < 1:
        raise ValueError(f"n_labs must be an integer >= 1, got {n_labs!r}")
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    labs = [draw_lab(model, seq, physical=physical, views=views, physical_seed=physical_seed)]
    labs += [draw_lab(model, lab_seed(seq, k), physical=physical, views=views) for k in range(1, int(n_labs))]
    return labs


def frames_alike(labs: Sequence[LabDraw], study: str = "pose") -> bool:
    """Whether every lab makes ``study``'s frames alike, so that the labs can share renders and
    segmentations in one task: the same transducer object and the same true views (projection
    matrices), and for ``"targeting"`` the same arm (equal kinematic errors, ``robot_accuracy``:
    they move the calibration poses). The range labs of a source other than the arm's keep lab 0's
    arm; labs drawn apart each have their own. Sharing is exact either way (frames are shared by
    content); this says only whether it would find anything."""
    labs = list(labs)
    first = labs[0]
    if study == "targeting":
        arms = [lab.kinematic_error() for lab in labs]
        if not all(_same_arm(arm, arms[0]) for arm in arms[1:]):
            return False
    return all(lab.physical is first.physical and len(lab.frame_views) == len(first.frame_views)
               and all(np.array_equal(a.P, b.P) for a, b in zip(lab.frame_views, first.frame_views))
               for lab in labs[1:])


def _same_arm(a, b) -> bool:
    """Whether two labs' kinematic errors (``LabDraw.kinematic_error``, None: the nominal arm) are equal."""
    if a is None or b is None:
        return a is None and b is None
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))


def _labs_task(task: tuple, *, setup: BudgetSetup, labs: Sequence[LabDraw], share: bool,
               centre_only: bool = False) -> pd.DataFrame:
    """The "lab" configuration of each lab of the task's chunk, on one experiment of one study."""
    study, seed, experiment, indices = task
    run = functools.partial(_pose_task, centre_only=centre_only) if study == "pose" else _targeting_task
    config = setup.pose_config if study == "pose" else setup.targeting_config
    frames = []
    scope = shared_work(setup, config) if share else contextlib.nullcontext((setup, None))
    with scope as (base, shared):
        for k in indices:
            lab = labs[k]
            frame = run(dataclasses.replace(base, lab=lab), seed, experiment, [("lab", lab.model)])
            frame.insert(0, "lab", int(k))
            frame.insert(0, "study", study)
            frames.append(frame)
    out = pd.concat(frames, ignore_index=True)
    for name in ("frames", "segmentations", "estimates"):
        out.attrs[name] = (getattr(shared, name).misses, getattr(shared, name).hits) if share else (0, 0)
    return out


def run_labs(setup: BudgetSetup, labs: Sequence[LabDraw], *, seed: int, indices: Sequence[int] | None = None,
             executor: SweepExecutor | str | None = None, labs_per_task: int | None = None,
             studies: Sequence[str] = ("pose", "targeting"), share: bool = True,
             centre_only: bool = False, progress: bool = False) -> pd.DataFrame:
    """Run every lab with all its sources on, on ``setup``'s pose and targeting experiments: the "lab"
    configuration of :func:`~histostudy.study.budget.run_error_budget` for each lab, number for number.

    One task per (study, experiment, chunk of labs) goes through :func:`histostudy.core.run_sweep`;
    the numbers depend neither on the executor nor on the chunks.

    Args:
        setup: the budget's set-up.
        labs: the labs (:func:`draw_labs`).
        seed: the study's integer seed.
        indices: the lab number of each of ``labs``; None: ``0, 1, ...``.
        executor: what runs the tasks (sequential, local processes, a dask cluster); None: the default.
        labs_per_task: labs per task; None: all in one chunk where their frames are alike
            (:func:`frames_alike`), else one.
        studies: ``"pose"`` and/or ``"targeting"``.
        share: share renders, segmentations and estimates between the labs of a chunk.
        centre_only: run only each pose experiment's centre acquisition (``run_pose_study``'s
            ``centre_only``): its rows' centre errors are the full run's, the margins' and radii's
            columns are left out; targeting experiments run whole.
        progress: a progress bar per task.

    Returns:
        One row per (study, lab, experiment): ``lab`` and ``run_error_budget``'s columns;
        ``attrs["frames"]``, ``attrs["segmentations"]`` and ``attrs["estimates"]``: (made, shared).

    Raises:
        TypeError: ``setup`` is not a BudgetSetup.
        ValueError: no labs, ``indices`` not naming each lab once, an unknown study, a bad
            ``labs_per_task``, or ``centre_only`` not a bool.
    """
    if not isinstance(setup, BudgetSetup):
        raise TypeError(f"setup must be a BudgetSetup, got {type(setup).__name__}")
    labs = list(labs)
    if not labs or not all(isinstance(lab, LabDraw) for lab in labs):
        raise ValueError("labs must be a non-empty sequence of LabDraw (draw_labs)")
    indices = list(range(len(labs))) if indices is None else [int(i) for i in indices]
    if len(indices) != len(labs) or len(set(indices)) != len(indices):
        raise ValueError(f"indices must name each of the {len(labs)} labs once, got {indices!r}")
    studies = tuple(studies)
    if not studies or any(s not in ("pose", "targeting") for s in studies):
        raise ValueError(f"studies must name 'pose' and/or 'targeting', got {studies!r}")
    if labs_per_task is not None and (isinstance(labs_per_task, bool) or not isinstance(labs_per_task, (int,
                                                                                                        np.integer))
                                      or labs_per_task < 1):
        raise ValueError(f"labs_per_task must be an integer >= 1 or None, got {labs_per_task!r}")
    if not isinstance(centre_only, bool):
        raise ValueError(f"centre_only must be True or False, got {centre_only!r}")
    tasks = []
    for study in studies:
        size = labs_per_task or (len(labs) if share and frames_alike(labs, study) else 1)
        chunks = [tuple(range(i, min(i + size, len(labs)))) for i in range(0, len(labs), size)]
        tasks += [(study, int(seed), e, chunk) for e in range(getattr(setup, f"{study}_config").n_experiments)
                  for chunk in chunks]
    frames = run_sweep(_labs_task, tasks, executor=executor, chunk_size=1, progress=progress,
                       shared={"setup": setup, "labs": labs, "share": share, "centre_only": centre_only})
    out = pd.concat(frames, ignore_index=True)
    out["lab"] = [indices[k] for k in out["lab"]]
    out = out.sort_values(["study", "lab", "experiment"], kind="stable").reset_index(drop=True)
    for name in ("frames", "segmentations", "estimates"):
        out.attrs[name] = tuple(int(sum(f.attrs[name][i] for f in frames)) for i in (0, 1))
    return out


def labs_records(budget_records: pd.DataFrame, more: pd.DataFrame | None = None) -> pd.DataFrame:
    """Lab 0's rows from :func:`~._run.run_error_budget`'s records (its "lab" configuration) as
    ``lab`` 0, and the rows of :func:`run_labs` for the other labs (``more``), in one table."""
    lab0 = budget_records[budget_records["configuration"] == "lab"].copy()
    lab0.insert(1, "lab", 0)
    frames = [lab0] if more is None or more.empty else [lab0, more[more["lab"] != 0]]
    out = pd.concat(frames, ignore_index=True)
    return out.sort_values(["study", "lab", "experiment"], kind="stable").reset_index(drop=True)


def _isocentre_shift_mm(a: View, b: View) -> float:
    origin = np.zeros((1, 3))
    return float(np.linalg.norm(a.project(origin) - b.project(origin)) * a.pixel_mm)


def lab_magnitudes(labs: Sequence[LabDraw], indices: Sequence[int] | None = None) -> pd.DataFrame:
    """One row per lab (``lab``), one column per systematic source of :data:`LAB_MAGNITUDES` that the
    labs' model has on: the size of that lab's draw (mm, as :data:`LAB_MAGNITUDES` says)."""
    labs = list(labs)
    indices = list(range(len(labs))) if indices is None else list(indices)
    rows = []
    for k, lab in zip(indices, labs):
        on = set(lab.model.enabled)
        row: dict[str, float] = {"lab": int(k)}
        if "manufacturing" in on:
            row["manufacturing"] = float(np.linalg.norm(lab.physical.focal_point_mm))
        if "bubble_offset" in on:
            row["bubble_offset"] = float(np.linalg.norm(lab.bubble_offset_mm))
        if "projection" in on:
            row["projection"] = float(np.mean([_isocentre_shift_mm(e, s)
                                               for e, s in zip(lab.estimator_views, lab.study_views)]))
        if "gantry_sag" in on:
            row["gantry_sag"] = float(np.mean([np.linalg.norm(f.source_mm - s.source_mm)
                                               for f, s in zip(lab.frame_views, lab.study_views)]))
        rows.append(row)
    return pd.DataFrame(rows)
