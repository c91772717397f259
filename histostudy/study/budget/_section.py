"""Notebook 07's section: its parameters (:class:`BudgetSectionConfig`), set-up (:func:`prepare`,
every draw from one ``seed``) and parts — the sources, the runs, the shares, the stand-ins — each
returning a :class:`~histostudy.study.section.SectionPart` that
:func:`~histostudy.study.section.record` writes (§III, §IV).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from histostudy.imaging import default_biplane
from histostudy.transducer import TransducerModel, TransducerSpec

from ..pose.experiments import PoseStudyConfig, study_stages
from ..section import (
    SectionPart,
    Timer,
    timer_or_untimed,
)
from ..targeting.setup import TargetingStudyConfig
from ._config import RECORDED_PARAMETERS, BudgetSectionConfig, BudgetSeeds, budget_seeds, lab_model_from_parameters
from ._references import SOURCE_REFERENCES
from ._run import BudgetSetup, run_error_budget, section_params, section_seeds
from ._sources import LabErrorModel, draw_lab
from ._summary import budget_comparisons, configuration_table, dominant_sources, source_shares, waterfall_figure

__all__ = ["BudgetRun", "BudgetSectionConfig", "BudgetSeeds", "RECORDED_PARAMETERS", "SECTION_TITLE",
           "SOURCE_PROVENANCE", "SharesSection", "budget_section", "budget_seeds", "closing_part",
           "closing_text", "lab_model_from_parameters", "prepare", "prepare_budget", "shares_section",
           "sources_part", "sources_table", "stand_ins"]

SECTION_TITLE = "07 · The error budget: the lab's error sources and their shares (§III, §IV)"

#: Where each source's default comes from (the report's sources table): its status, value, range
#: and reference (:data:`~._references.SOURCE_REFERENCES`).
SOURCE_PROVENANCE = {name: ref.provenance for name, ref in SOURCE_REFERENCES.items()}


def prepare(params: BudgetSectionConfig | Mapping, seed: int, *, timer: Timer | None = None) -> BudgetSetup:
    """The section's set-up (:func:`prepare_budget`) from its checked parameters.

    Args:
        params: a :class:`BudgetSectionConfig`, or a mapping naming its fields (the notebook's ``globals()``).
        seed: the notebook's root seed (:func:`budget_seeds`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`~histostudy.study.budget.BudgetSetup`, keeping ``params`` and the seeds.

    Raises:
        ValueError: a parameter missing or refused (:class:`BudgetSectionConfig`).
    """
    if not isinstance(params, BudgetSectionConfig):
        params = BudgetSectionConfig.from_parameters(params)
    return dataclasses.replace(prepare_budget(params.recorded(), seed, timer=timer), params=params,
                               seeds=budget_seeds(seed))


def prepare_budget(parameters: Mapping, seed: int, *, timer: Timer | None = None) -> BudgetSetup:
    """Build the models (``pose_spacing_mm``, ``render_spacing_mm``; the study's physical
    transducer from the seed), the default biplane views, the lab (:func:`draw_lab`), both
    studies' configurations (the pose experiments: margins in the paper's fast mode, occlusion-aware
    maps, no warm-start rows; the targeting experiments: no bias correction, as the paper) and
    the stages (``learned_stages``)."""
    seeds = budget_seeds(seed)
    spec = TransducerSpec()
    model = lab_model_from_parameters(parameters["sources"])
    render = dict(photons_per_pixel=parameters["photons_per_pixel"], n_splats=parameters["n_splats"],
                  splat_sigma_mm=parameters["splat_sigma_mm"], background=parameters["background"],
                  splat_device=parameters["splat_device"])
    pose_config = PoseStudyConfig(n_experiments=int(parameters["pose_experiments"]), modes=("fast",),
                                  distance_maps=("occlusion_aware",), track=False, **render)
    targeting_config = TargetingStudyConfig(n_experiments=int(parameters["targeting_experiments"]),
                                            bias_correction=False, **render)
    with (timer or (lambda name: contextlib.nullcontext()))("build models and the lab"):
        pose_model = TransducerModel.build(spec, spacing_mm=parameters["pose_spacing_mm"])
        render_model = TransducerModel.build(spec, spacing_mm=parameters["render_spacing_mm"])
        physical = TransducerModel.build_physical(spec, spacing_mm=parameters["render_spacing_mm"],
                                                  rng=np.random.default_rng(seeds.physical))
        lab = draw_lab(model, seeds.lab, physical=physical, views=default_biplane(), physical_seed=seeds.physical)
    stages = study_stages(pose_config, parameters["learned_stages"])
    return BudgetSetup(lab, pose_config, targeting_config, pose_model, render_model, stages.segmenter,
                       stages.orientation)


def sources_table(model: LabErrorModel) -> pd.DataFrame:
    """One row per source: on or off, its magnitudes and where the default comes from."""
    rows = model.describe()
    for row in rows:
        row["from"] = SOURCE_PROVENANCE[row["source"]]
    return pd.DataFrame(rows)


def stand_ins() -> list[tuple[str, str]]:
    """``(lab, synthetic)``: what stands in for what in the budget."""
    return [("the lab's C-arm, transducer, phantom and observer",
             "LabErrorModel's documented sources drawn once per lab (systematic) and per experiment (random)"),
            ("manual annotation of the treated zone",
             "the automatic zone segmentation plus the annotation source's centroid and radius errors"),
            ("the paper's 10 pose and 6 targeting studies", "the budget's pose and targeting experiments, "
             "every configuration on the same draws")]


def closing_text(setup: BudgetSetup, n_pose: int, n_targeting: int, n_labs: int = 1) -> str:
    """The section's closing paragraph: the lab drawn (its bubble offset and transducer focal
    offset), the experiments run and, with ``n_labs`` > 1, what the comparisons with the paper
    rest on."""
    lab = setup.lab
    labs = ("" if n_labs <= 1 else f" The comparisons with the paper below are the median over {n_labs} labs "
            "(each lab's mean over its experiments, all sources on), with the labs' 5-95 % band in the note.")
    return (f"{n_pose} pose and {n_targeting} targeting experiment(s) per configuration, one lab (lab 0). This lab's "
            f"bubble offset is {np.round(lab.bubble_offset_mm, 2).tolist()} mm (LR, TB, -depth; transducer frame); "
            f"its transducer's focal point lies {np.linalg.norm(lab.physical.focal_point_mm):.2f} mm from the digital "
            f"model's (the study's transducer: {np.linalg.norm(lab.study_physical.focal_point_mm):.2f} mm). A single "
            "lab draws each systematic source once: its bias is one draw of the sources' distribution, as the "
            "paper's was." + labs)


# --- the notebook's parts: tables, figures, values and comparisons for record() ---------------------


def sources_part(setup: BudgetSetup) -> SectionPart:
    """The lab's error sources (:func:`sources_table`).

    Args:
        setup: the budget's set-up (:func:`prepare`).

    Returns:
        The part: table ``sources`` (on or off, magnitudes, where each default comes from).
    """
    return SectionPart(tables={"sources": (sources_table(setup.lab.model), "The lab's error sources: on or off, "
                                           "their magnitudes, and where each default comes from (none fitted to the "
                                           "paper's figures)")})


@dataclass(frozen=True, eq=False)
class BudgetRun:
    """The budget run (:func:`budget_section`): its ``records``, the per-configuration tables of
    both studies (``pose_table``, ``targeting_table``) and the report's ``part``."""

    records: pd.DataFrame
    pose_table: pd.DataFrame
    targeting_table: pd.DataFrame
    part: SectionPart


def budget_section(setup: BudgetSetup, *, timer: Timer | None = None) -> BudgetRun:
    """Every configuration run (:func:`~histostudy.study.budget.run_error_budget` on the set-up's
    study seed and ``params.scheduler``, timed as ``"budget"``).

    Args:
        setup: the budget's set-up (:func:`prepare`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`BudgetRun`: the records and each study's table per configuration (mm); its part:
        tables ``pose_configurations`` and ``targeting_configurations``.

    Raises:
        ValueError: ``setup`` has no ``params`` or ``seeds`` (not made by :func:`prepare`).
    """
    with timer_or_untimed(timer)("budget"):
        records = run_error_budget(setup, seed=section_seeds(setup).study,
                                   executor=section_params(setup).scheduler or None)
    pose_table, targeting_table = configuration_table(records, "pose"), configuration_table(records, "targeting")
    return BudgetRun(records, pose_table, targeting_table, SectionPart(tables={
        "pose_configurations": (pose_table, "Table II's centre error per configuration (mm): mean, SD and RMS of the "
                                "Euclidean error, bias and MAE per direction, radius MAE; n experiments with an "
                                "estimate"),
        "targeting_configurations": (targeting_table, "The targeting error per configuration (mm), as the lab "
                                     "measures it")}))


@dataclass(frozen=True, eq=False)
class SharesSection:
    """One study's shares of the error (:func:`shares_section`): the ``shares`` table
    (:func:`source_shares`) and the report's ``part``."""

    shares: pd.DataFrame
    part: SectionPart


def shares_section(records: pd.DataFrame, study: str) -> SharesSection:
    """One study's shares of the lab's mean squared error increment (docs/error-budget.md, "The design").

    Args:
        records: :func:`~histostudy.study.budget.run_error_budget`'s rows.
        study: ``"pose"`` or ``"targeting"``.

    Returns:
        The :class:`SharesSection`: the shares (alone and total, mm²; the bias each adds alone, mm);
        its part: table ``<study>_shares``, figure ``<study>_waterfall``, value ``<study>_dominant``.

    Raises:
        ValueError: ``study`` unknown, or ``records`` not run_error_budget's table.
    """
    shares = source_shares(records, study)
    return SharesSection(shares, SectionPart(
        tables={f"{study}_shares": (shares, f"{study}: each source's share of the lab's MSE increment (alone: only "
                                    "that source on; total: the lab without it), and the bias it adds alone (mm)")},
        figures={f"{study}_waterfall": (waterfall_figure(shares, study), f"{study}: the mean squared error from the "
                                        "baseline to the lab, source by source (first-order increments, then the "
                                        "interactions)")},
        values={f"{study}_dominant": dominant_sources(shares)}))


def closing_part(setup: BudgetSetup, records: pd.DataFrame, labs: pd.DataFrame | None = None) -> SectionPart:
    """The lab beside the paper, what stands in for what and the closing paragraph.

    Args:
        setup: the budget's set-up (:func:`prepare`).
        records: :func:`~histostudy.study.budget.run_error_budget`'s rows.
        labs: the many labs' statistics (:func:`~histostudy.study.budget._distribution.lab_statistics`);
            with them the "lab" comparisons are their distribution; None: lab 0 alone.

    Returns:
        The part: the comparisons with the paper, the stand-ins and one paragraph.

    Raises:
        ValueError: ``setup`` has no ``params`` (not made by :func:`prepare`).
    """
    p = section_params(setup)
    n_labs = 1 if labs is None else int(labs["lab"].nunique())
    return SectionPart(comparisons=tuple(budget_comparisons(records, labs)), stand_ins=tuple(stand_ins()),
                       texts=(closing_text(setup, p.pose_experiments, p.targeting_experiments, n_labs),))
