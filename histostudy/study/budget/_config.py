"""Notebook 07's checked parameters (:class:`BudgetSectionConfig`) and seeds (:class:`BudgetSeeds`),
apart from the section so that the budget's runs (``_run``) can name them without importing it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from histostudy.core import check_count, check_positive
from histostudy.imaging import BACKGROUNDS

from ..section import RenderedSectionConfig, check_bool, check_choice, check_splat_device, check_text
from ._sources import LAB_SOURCES, LabErrorModel

__all__ = ["RECORDED_PARAMETERS", "BudgetSectionConfig", "BudgetSeeds", "budget_seeds", "lab_model_from_parameters"]

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "splat_device", "pose_spacing_mm",
                       "render_spacing_mm", "background", "pose_experiments", "targeting_experiments", "learned_stages",
                       "sources", "n_labs", "range_sources", "scheduler")


@dataclass(frozen=True)
class BudgetSectionConfig(RenderedSectionConfig):
    """Notebook 07's parameters (its ``parameters`` cell names and documents each), checked; values
    are kept as given, ``sources`` and ``range_sources`` as tuples.

    Args:
        photons_per_pixel: dose of the frames, photons per unattenuated pixel (> 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: splat SD (mm, > 0).
        pose_spacing_mm: grid of the digital model the pose is estimated with (mm, > 0).
        render_spacing_mm: grid of the models the frames are rendered from, and the lab's transducer (mm, > 0).
        background: the scene behind the transducer (one of :data:`histostudy.imaging.BACKGROUNDS`).
        splat_device: where the frames are splatted, one of :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        pose_experiments: Table II experiments per configuration (>= 1).
        targeting_experiments: targeting experiments per configuration (>= 1).
        learned_stages: the estimates on the shipped U-Net and VGG19 where they qualify.
        sources: the lab's sources on (names of :data:`~histostudy.study.budget.LAB_SOURCES`, each at most once).
        n_labs: labs drawn for the distribution (>= 1; lab 0 the one the configurations run on).
        range_sources: sources run at both ends of their range on lab 0 (each on in ``sources``).
        scheduler: where the experiments run (``""``: ``HISTOSTUDY_SCHEDULER``, else here;
            ``"local:<n>"``; ``"tcp://<host>:<port>"``).

    Raises:
        ValueError: a bad value, named with its value and what it must be.
    """

    NOTEBOOK = "07"
    RECORDED = RECORDED_PARAMETERS

    pose_experiments: int
    targeting_experiments: int
    learned_stages: bool
    sources: tuple
    n_labs: int
    range_sources: tuple
    scheduler: str

    def __post_init__(self):
        for name, unit in (("photons_per_pixel", "photons per pixel"), ("splat_sigma_mm", "mm"),
                           ("pose_spacing_mm", "mm"), ("render_spacing_mm", "mm")):
            check_positive(getattr(self, name), name, unit=unit)
        for name in ("n_splats", "pose_experiments", "targeting_experiments", "n_labs"):
            check_count(getattr(self, name), name)
        check_choice(self.background, "background", BACKGROUNDS)
        check_splat_device(self.splat_device)
        object.__setattr__(self, "learned_stages", check_bool(self.learned_stages, "learned_stages"))
        if isinstance(self.sources, (str, bytes)) or not isinstance(self.sources, (list, tuple)):
            raise ValueError(f"sources must be a list of the names {LAB_SOURCES}, got {self.sources!r}")
        lab_model_from_parameters(self.sources)  # each name known, at most once
        object.__setattr__(self, "sources", tuple(self.sources))
        ranges = self.range_sources
        if (isinstance(ranges, (str, bytes)) or not isinstance(ranges, (list, tuple))
                or any(r not in self.sources for r in ranges) or len(set(ranges)) != len(ranges)):
            raise ValueError(f"range_sources must be a list of sources on in sources {list(self.sources)}, each at "
                             f"most once, got {ranges!r}")
        object.__setattr__(self, "range_sources", tuple(ranges))
        check_text(self.scheduler, "scheduler", '"" (HISTOSTUDY_SCHEDULER, else here), "local:<n>" or '
                                                '"tcp://<host>:<port>"')




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
