"""The error budget (§III, §IV): Table II and the targeting study run under a lab's error sources,
all on, each alone and all but one, on the same draws, sharing work where it is exact; one task
per (study, experiment) on :func:`histostudy.core.run_sweep`. C-arm frame, mm; errors along
depth/TB/LR (docs/error-budget.md, "The design").
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from histostudy.calibration import CalibrationError
from histostudy.core import SweepExecutor, run_sweep
from histostudy.learning import OrientationSource, Segmenter
from histostudy.transducer import TransducerModel

from ..pose.experiments import PoseStudyConfig, run_pose_study
from ..pose.geometry import DIRECTIONS
from ..pose.metrics import experiment_metrics
from ..pose.reference import cbct_reference
from ..targeting.experiment import run_targeting_experiment
from ..targeting.robots import sim_robot
from ..targeting.setup import TargetingError, TargetingStudyConfig
from ._config import BudgetSectionConfig, BudgetSeeds
from ._shared import shared_work
from ._sources import ExperimentDraw, LabDraw, LabErrorModel

__all__ = ["BudgetSetup", "ESTIMATE_SOURCES", "budget_configurations", "measured_reference", "measured_zone",
           "run_error_budget"]

#: The sources that change the frames or what the estimator is told (everything else acts after).
ESTIMATE_SOURCES = ("manufacturing", "projection", "gantry_sag", "robot", "carm_reproducibility", "robot_accuracy")

#: The pose study's: the robot's accuracy is not modelled there (its centre pose is measured, not
#: commanded; a margin move of r errs by about accuracy/reach x r, a hundredth of a millimetre).
_POSE_ESTIMATE_SOURCES = tuple(s for s in ESTIMATE_SOURCES if s != "robot_accuracy")


def budget_configurations(model: LabErrorModel) -> list[tuple[str, LabErrorModel]]:
    """``(label, sub-model)``: ``"baseline"`` (every source off: the studies as notebooks 04 and 05
    run them), ``"lab"`` (``model``), ``"only <source>"`` and ``"without <source>"`` for each
    source ``model`` has on."""
    if not isinstance(model, LabErrorModel):
        raise TypeError(f"model must be a LabErrorModel, got {type(model).__name__}")
    out = [("baseline", model.off()), ("lab", model)]
    out += [(f"only {name}", model.only(name)) for name in model.enabled]
    out += [(f"without {name}", model.without(name)) for name in model.enabled]
    return out


def _key(model: LabErrorModel, names: Sequence[str]) -> tuple[bool, ...]:
    return tuple(getattr(model, n) is not None for n in names)


@dataclass(frozen=True, eq=False)
class BudgetSetup:
    """What the budget runs with (made by notebook 07's ``prepare``, or by hand for a lab's own figures).

    Args:
        lab: the lab drawn (:func:`~histostudy.study.budget.draw_lab`).
        pose_config: the pose study's parameters (its ``n_experiments`` the budget's; bubble offset zeros).
        targeting_config: the targeting study's (likewise; the budget predicts without a bias correction).
        pose_model: the digital model the pose is estimated with.
        render_model: the model frames are rendered from.
        segmenter: the segmentation stage; None: each study's oracle.
        orientation: the orientation source; None: the oracle.
        params: notebook 07's checked parameters (:class:`~histostudy.study.budget.BudgetSectionConfig`), if any.
        seeds: its seeds (:class:`~histostudy.study.budget._section.BudgetSeeds`), if any.

    Raises:
        TypeError: ``lab`` is not a LabDraw.
        ValueError: a config's ``bubble_offset_mm`` not zeros (the lab's offset replaces it).
    """

    lab: LabDraw
    pose_config: PoseStudyConfig
    targeting_config: TargetingStudyConfig
    pose_model: TransducerModel
    render_model: TransducerModel
    segmenter: Segmenter | None = None
    orientation: OrientationSource | None = None
    params: BudgetSectionConfig | None = None
    seeds: BudgetSeeds | None = None

    def __post_init__(self):
        if not isinstance(self.lab, LabDraw):
            raise TypeError(f"lab must be a LabDraw (draw_lab), got {type(self.lab).__name__}")
        for name in ("pose_config", "targeting_config"):
            if np.any(np.asarray(getattr(self, name).bubble_offset_mm, float) != 0):
                raise ValueError(f"{name}.bubble_offset_mm must be zeros: the lab model's bubble_offset replaces it, "
                                 f"got {getattr(self, name).bubble_offset_mm!r}")


def section_params(setup: BudgetSetup) -> BudgetSectionConfig:
    """``setup.params``, which notebook 07's parts read.

    Raises:
        ValueError: ``setup`` has none (a set-up made without notebook 07's ``prepare``).
    """
    if setup.params is None:
        raise ValueError("setup.params is None: expected notebook 07's checked parameters (a BudgetSetup made by "
                         "prepare)")
    return setup.params


def section_seeds(setup: BudgetSetup) -> BudgetSeeds:
    """``setup.seeds``, which notebook 07's parts draw from.

    Raises:
        ValueError: ``setup`` has none (a set-up made without notebook 07's ``prepare``).
    """
    if setup.seeds is None:
        raise ValueError("setup.seeds is None: expected notebook 07's seeds (a BudgetSetup made by prepare)")
    return setup.seeds


def measured_reference(reference: pd.DataFrame, draw: ExperimentDraw) -> pd.DataFrame:
    """The CBCT reference of one experiment as the lab reads it: centroid and fitted sphere moved
    with the phantom, read through the registration and annotated (centre and radii)."""
    out = reference.copy()
    for i in out.index:
        for prefix in ("centroid", "sphere"):
            cols = [f"{prefix}_{a}" for a in "xyz"]
            out.loc[i, cols] = draw.measured_point(out.loc[i, cols].to_numpy(float))
        for d, err in zip(DIRECTIONS, draw.annotation_radius_mm):
            out.loc[i, f"ref_radius_{d}"] = float(out.loc[i, f"ref_radius_{d}"]) + float(err)
        out.loc[i, "sphere_radius_mm"] = float(out.loc[i,
                                                       "sphere_radius_mm"]) + float(np.mean(draw.annotation_radius_mm))
    return out


def measured_zone(row: dict, draw: ExperimentDraw) -> dict:
    """A targeting row's zone errors as the lab measures them (mm along the commanded axes).

    The robot is commanded to the target's coordinates as read from the pre-treatment CBCT
    (through the registration), so the zone lands shifted by the reading's error (the
    calibration's error is the same a millimetre away); its centroid is then read from the
    post-treatment CBCT (moved with the phantom, through the registration, annotated)."""
    target = np.array([row[f"target_{a}"] for a in "xyz"])
    centroid = np.array([row[f"centroid_{a}"] for a in "xyz"])
    target_read = draw.read_target(target)
    err = draw.measured_point(centroid + (target_read - target)) - target_read
    out = {}
    for d in DIRECTIONS:
        axis = np.array([row[f"axis_{d}_{a}"] for a in "xyz"])
        out[f"err_{d}"] = float(err @ axis)
    out["err_euclidean"] = float(np.linalg.norm(err))
    out["radius_err_mm"] = float(row["radius_err_mm"] + np.mean(draw.annotation_radius_mm))
    return out


def _pose_task(setup: BudgetSetup, seed: int, experiment: int,
               configurations: list[tuple[str, LabErrorModel]], *, centre_only: bool = False) -> pd.DataFrame:
    """Table II's per-experiment metrics under every configuration, for one pose experiment (its
    centre's only with ``centre_only``: ``run_pose_study``'s)."""
    lab, base = setup.lab, setup.pose_config
    records, references, rows = {}, {}, []
    for label, model in configurations:
        sub = lab.variant(model)
        draw = sub.experiment(experiment)
        config = dataclasses.replace(base,
                                     robot_repeatability_mm=sub.robot_repeatability_mm(base.robot_repeatability_mm),
                                     bubble_offset_mm=tuple(float(v) for v in sub.bubble_offset_at(experiment)),
                                     assumed_bubble_offset_mm=(0.0, 0.0, 0.0))
        key = _key(model, _POSE_ESTIMATE_SOURCES)
        if key not in records:
            records[key] = run_pose_study(config, pose_model=setup.pose_model, render_model=setup.render_model,
                                          physical=sub.physical, views=sub.frame_views,
                                          estimator_views=sub.estimator_views, seed=seed,
                                          segmenter=setup.segmenter, orientation=setup.orientation,
                                          experiments=[experiment], acquisition_views=sub.acquisition_views,
                                          centre_only=centre_only)
        ref_key = _key(model, ("manufacturing", "bubble_offset", "robot", "replacement"))
        if ref_key not in references:
            references[ref_key] = cbct_reference(config, physical=sub.physical, seed=seed, experiments=[experiment])
        rec, ref = records[key], references[ref_key]
        n_failed = int((~rec["ok"].astype(bool)).sum())
        if not bool(ref["ok"].iloc[0]):
            rows.append({"configuration": label, "experiment": experiment, "n_failed": n_failed,
                         "failure": f"no CBCT reference: {ref['failure'].iloc[0]}"})
            continue
        metrics = experiment_metrics(rec, reference=measured_reference(ref, draw))
        for _, m in metrics.iterrows():
            rows.append({"configuration": label, **m.to_dict(), "n_failed": n_failed,
                         "failure": "; ".join(rec.loc[~rec["ok"].astype(bool), "failure"].astype(str))})
    return pd.DataFrame(rows)


def _targeting_task(setup: BudgetSetup, seed: int, experiment: int,
                    configurations: list[tuple[str, LabErrorModel]]) -> pd.DataFrame:
    """The targeting errors under every configuration, for one targeting experiment."""
    lab, base = setup.lab, setup.targeting_config
    seq = np.random.SeedSequence(seed).spawn(base.n_experiments)[experiment]
    runs, rows = {}, []
    for label, model in configurations:
        sub = lab.variant(model)
        draw = sub.experiment(10_000 + experiment)  # the targeting study's own experiments
        key = _key(model, (*ESTIMATE_SOURCES, "bubble_offset", "replacement"))
        if key not in runs:
            config = dataclasses.replace(
                base, bias_correction=False,
                robot_repeatability_mm=sub.robot_repeatability_mm(base.robot_repeatability_mm),
                bubble_offset_mm=tuple(float(v) for v in sub.bubble_offset_at(10_000 + experiment)))
            views = functools.partial(sub.acquisition_views, 10_000 + experiment)
            try:
                runs[key] = run_targeting_experiment(
                    config, seq, pose_model=setup.pose_model, render_model=setup.render_model, physical=sub.physical,
                    views=sub.frame_views, estimator_views=sub.estimator_views,
                    robot_factory=sim_robot(config, sub.kinematic_error()), experiment=experiment,
                    segmenter=setup.segmenter, orientation=setup.orientation, acquisition_views=views)
            except (TargetingError, CalibrationError) as exc:  # the lab would redo the calibration
                runs[key] = {"failure": str(exc)}
        run = runs[key]
        if "failure" in run:
            rows.append({"configuration": label, "experiment": experiment, "ok": False, "failure": run["failure"]})
            continue
        rows.append({"configuration": label, "experiment": experiment, "ok": True, "failure": "",
                     "diameter_mm": run["diameter_mm"], "cal_error_at_target_mm": run["cal_error_at_target_mm"],
                     **measured_zone(run, draw)})
    return pd.DataFrame(rows)


def _run_task(task: tuple, *, setup: BudgetSetup, configurations: list) -> pd.DataFrame:
    study, seed, experiment = task
    config = setup.pose_config if study == "pose" else setup.targeting_config
    # Configurations whose frames are alike (the sources that act on the views the estimator is told,
    # or after it) render and segment them once, and estimate once where the views told are alike too:
    # exact, the numbers of separate runs (_shared).
    with shared_work(setup, config, max_frames=64) as (shared, _):
        frame = (_pose_task if study == "pose" else _targeting_task)(shared, seed, experiment, configurations)
    frame.insert(0, "study", study)
    return frame


def run_error_budget(setup: BudgetSetup, *, seed: int, configurations: list[tuple[str, LabErrorModel]] | None = None,
                     executor: SweepExecutor | str | None = None, progress: bool = False,
                     studies: Sequence[str] = ("pose", "targeting")) -> pd.DataFrame:
    """Run every configuration on the pose and the targeting experiments of ``setup``'s
    configurations, all on the same draws (docs/error-budget.md, "The design").

    Args:
        setup: the budget's set-up.
        seed: the studies' integer seed.
        configurations: ``(label, sub-model)`` pairs with unique labels including ``"baseline"``;
            None: :func:`budget_configurations` of the lab's model.
        executor: what runs the tasks (:func:`histostudy.core.run_sweep`; the numbers do not depend
            on it); None: the default.
        progress: a progress bar per task.
        studies: ``"pose"`` and/or ``"targeting"``.

    Returns:
        One row per (study, configuration, experiment): for ``"pose"`` the columns of
        :func:`~histostudy.study.pose.metrics.experiment_metrics` against the lab's reading of the
        CBCT reference and ``n_failed``; for ``"targeting"`` the measured zone's ``err_<d>``,
        ``err_euclidean``, ``radius_err_mm``, ``cal_error_at_target_mm``, ``ok`` and ``failure``
        (mm, along depth/TB/LR).

    Raises:
        TypeError: ``setup`` is not a BudgetSetup.
        ValueError: an unknown study, or configurations without unique labels and ``"baseline"``.
    """
    if not isinstance(setup, BudgetSetup):
        raise TypeError(f"setup must be a BudgetSetup, got {type(setup).__name__}")
    studies = tuple(studies)
    if not studies or any(s not in ("pose", "targeting") for s in studies):
        raise ValueError(f"studies must name 'pose' and/or 'targeting', got {studies!r}")
    configurations = budget_configurations(setup.lab.model) if configurations is None else list(configurations)
    labels = [label for label, _ in configurations]
    if "baseline" not in labels or len(set(labels)) != len(labels):
        raise ValueError(f"configurations must have unique labels including 'baseline', got {labels}")
    tasks = [("pose", int(seed), e) for e in range(setup.pose_config.n_experiments) if "pose" in studies]
    tasks += [("targeting", int(seed), e) for e in range(setup.targeting_config.n_experiments)
              if "targeting" in studies]
    frames = run_sweep(_run_task, tasks, executor=executor, shared={"setup": setup, "configurations": configurations},
                       chunk_size=1, progress=progress)
    return pd.concat(frames, ignore_index=True)
