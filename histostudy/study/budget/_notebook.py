"""Notebook 07's set-up and prose: its parameters to a :class:`~.error_budget.BudgetSetup` (the lab
error model, the two studies' configurations, the models, the stages), the seeds, the sources'
table and what stands in for what (§III, §IV).

Every random draw of the notebook comes from one integer ``seed`` (:func:`budget_seeds`).
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
import pandas as pd

from histostudy.imaging import default_biplane
from histostudy.transducer import TransducerModel, TransducerSpec
from ._run import BudgetSetup
from ._sources import LAB_SOURCES, LabErrorModel, draw_lab
from ..pose._config import PoseStudyConfig, study_stages
from ..targeting._setup import TargetingStudyConfig

__all__ = ["BudgetSeeds", "RECORDED_PARAMETERS", "SECTION_TITLE", "SOURCE_PROVENANCE", "budget_seeds", "closing_text",
           "lab_model_from_parameters", "prepare_budget", "sources_table", "stand_ins"]

SECTION_TITLE = "07 · The error budget: the lab's error sources and their shares (§III, §IV)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "pose_spacing_mm", "render_spacing_mm",
                       "background", "pose_experiments", "targeting_experiments", "learned_stages", "sources",
                       "scheduler")

#: Where each source's default comes from (the report's sources table).
SOURCE_PROVENANCE = {
    "manufacturing": "ISO 2768-1 class m for a 120-400 mm part (±0.5 mm, ±0°10'), read as uniform; the study's "
                     "own assumption is 0.2 mm / 0.15°",
    "bubble_offset": "assumption: a sixth of the 3 x 3 x 6 mm bubble cloud (§II-C) per axis; one offset per "
                     "transducer (a bias), uncorrected as in the paper's targeting",
    "projection": "assumption: 0.5 px residual reprojection error of a phantom calibration, focal spot within 1 mm",
    "gantry_sag": "assumption: 0.5 mm along gravity per plane, what the calibration misses at a fluoroscopic angle",
    "registration": "assumption: a same-C-arm CBCT-to-fluoroscopy registration reproducible to 0.3 mm / 0.1°",
    "annotation": "derived: each extreme point of a hand-drawn sphere within ±1 voxel of a 1 mm CBCT",
    "robot": "the paper: UR5e pose repeatability ±0.03 mm (§II-C), taken as one SD",
    "phantom_motion": "assumption: an agarose phantom in a water bath, between treatment and CBCT",
}


@dataclass(frozen=True)
class BudgetSeeds:
    """The notebook's independent seeds: the study's physical transducer (whose quadrants the lab's
    tolerances move), the lab's draws, and the two studies' experiments (an integer)."""

    physical: np.random.SeedSequence
    lab: np.random.SeedSequence
    study: int


def budget_seeds(seed: int) -> BudgetSeeds:
    """The three children of ``SeedSequence(seed)``, in that order."""
    physical, lab, study = np.random.SeedSequence(int(seed)).spawn(3)
    return BudgetSeeds(physical, lab, int(study.generate_state(1)[0]))


def lab_model_from_parameters(sources) -> LabErrorModel:
    """The default :class:`LabErrorModel` with only ``sources`` on (a list of names of
    :data:`LAB_SOURCES`; every name at most once)."""
    sources = list(sources)
    unknown = [s for s in sources if s not in LAB_SOURCES]
    if unknown or len(set(sources)) != len(sources):
        raise ValueError(f"sources must name each of {LAB_SOURCES} at most once, got {sources!r}")
    model = LabErrorModel()
    return dataclasses.replace(model, **{name: None for name in LAB_SOURCES if name not in sources})


def prepare_budget(parameters: Mapping, seed: int, *,
                   timer: Callable[[str], contextlib.AbstractContextManager] | None = None) -> BudgetSetup:
    """Build the models (``pose_spacing_mm``, ``render_spacing_mm``; the study's physical
    transducer from the seed), the default biplane views, the lab (:func:`draw_lab`), both
    studies' configurations (``pose_experiments``: margins in the paper's fast mode, occlusion-aware
    maps, no warm-start rows; ``targeting_experiments``: no bias correction, as the paper) and
    the stages (``learned_stages``)."""
    seeds = budget_seeds(seed)
    spec = TransducerSpec()
    model = lab_model_from_parameters(parameters["sources"])
    render = dict(photons_per_pixel=parameters["photons_per_pixel"], n_splats=parameters["n_splats"],
                  splat_sigma_mm=parameters["splat_sigma_mm"], background=parameters["background"])
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


def closing_text(setup: BudgetSetup, n_pose: int, n_targeting: int) -> str:
    """The section's closing paragraph: the lab drawn (its bubble offset and transducer focal
    offset) and the experiments run."""
    lab = setup.lab
    return (f"{n_pose} pose and {n_targeting} targeting experiment(s) per configuration, one lab. This lab's "
            f"bubble offset is {np.round(lab.bubble_offset_mm, 2).tolist()} mm (LR, TB, -depth; transducer frame); "
            f"its transducer's focal point lies {np.linalg.norm(lab.physical.focal_point_mm):.2f} mm from the digital "
            f"model's (the study's transducer: {np.linalg.norm(lab.study_physical.focal_point_mm):.2f} mm). A single "
            "lab draws each systematic source once: its bias is one draw of the sources' distribution, as the "
            "paper's was.")
