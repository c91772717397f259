"""Notebook 05's set-up and prose: its parameters to a :class:`TargetingStudyConfig`, the transducer
models (spacings in mm), the views and the pose-estimation stages, the seeds of its random draws,
and what the report says stands in for the lab (§II-C, §II-D, §III).

Every random draw of the notebook comes from one integer ``seed`` through
:func:`notebook_seeds`, so a profile's seed fixes every number of the section.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from histostudy.imaging import View, default_biplane
from histostudy.transducer import TransducerModel, TransducerSpec
from ..pose import StudyStages, study_stages
from ._experiment import run_targeting_study
from ._setup import TargetingStudyConfig

__all__ = ["RECORDED_PARAMETERS", "SECTION_TITLE", "NotebookSeeds", "TargetingSetup", "closing_text",
           "config_from_parameters", "notebook_seeds", "prepare_study", "run_prepared_study", "stand_ins"]

SECTION_TITLE = "05 · Automated targeting: calibration, positioning, treatment (§II-C, §II-D, §II-E.4, §III)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "pose_spacing_mm", "render_spacing_mm",
                       "background", "n_experiments", "zone_diameters_mm", "n_calibration_poses", "pose_mode",
                       "degradation", "learned_stages", "phantom_voxel_mm", "cbct_voxel_mm", "treatment_spacing_mm",
                       "bubble_offset_mm", "bias_correction", "robot")


@dataclass(frozen=True)
class NotebookSeeds:
    """The notebook's independent seeds: the physical transducer's manufacturing deviations, the
    study (the integer of :func:`run_targeting_study`), the calibration-sensitivity Monte-Carlo and
    the 3-D scene's point sampling."""

    physical: np.random.SeedSequence
    study: int
    sensitivity: np.random.SeedSequence
    scene: np.random.SeedSequence


def notebook_seeds(seed: int) -> NotebookSeeds:
    """The four children of ``SeedSequence(seed)``, in that order (a child depends only on the seed
    and its index, so adding a consumer at the end changes none of the others)."""
    physical, study, sensitivity, scene = np.random.SeedSequence(seed).spawn(4)
    return NotebookSeeds(physical, int(study.generate_state(1)[0]), sensitivity, scene)


def config_from_parameters(parameters: Mapping) -> TargetingStudyConfig:
    """The study's configuration from the notebook's parameters: every entry named as a
    :class:`TargetingStudyConfig` field, lists made tuples (the rest keep the config's defaults)."""
    fields = {f.name for f in dataclasses.fields(TargetingStudyConfig)}
    return TargetingStudyConfig(**{name: tuple(value) if isinstance(value, list) else value
                                   for name, value in parameters.items() if name in fields})


@dataclass(frozen=True)
class TargetingSetup:
    """What the notebook's experiments run with: the configuration, the digital model the pose is
    estimated with, the (finer) model frames are rendered from, the physical transducer, the
    biplane views, the pose-estimation stages and the seeds."""

    config: TargetingStudyConfig
    pose_model: TransducerModel
    render_model: TransducerModel
    physical: TransducerModel
    views: Sequence[View]
    stages: StudyStages
    seeds: NotebookSeeds


def prepare_study(parameters: Mapping, seed: int, *,
                  timer: Callable[[str], contextlib.AbstractContextManager] | None = None) -> TargetingSetup:
    """Build the models (``pose_spacing_mm``, ``render_spacing_mm``; the physical transducer drawn
    from the seed), the default biplane views, the configuration and the stages
    (:func:`~.pose_estimation.study_stages` with ``learned_stages``) from the notebook's
    parameters. ``timer(name)``: a context manager timing the model build (e.g.
    ``SectionWriter.timer``)."""
    seeds = notebook_seeds(seed)
    spec = TransducerSpec()
    with (timer or (lambda name: contextlib.nullcontext()))("build models"):
        pose_model = TransducerModel.build(spec, spacing_mm=parameters["pose_spacing_mm"])
        render_model = TransducerModel.build(spec, spacing_mm=parameters["render_spacing_mm"])
        physical = TransducerModel.build_physical(spec, spacing_mm=parameters["render_spacing_mm"],
                                                  rng=np.random.default_rng(seeds.physical))
    views = default_biplane()
    config = config_from_parameters(parameters)
    # The calibration's pose estimates run on the shipped U-Net and VGG19 where their manifests meet
    # histostudy.pose.LEARNED_STAGE_REQUIREMENTS, otherwise on the oracles; the report says which.
    stages = study_stages(config, parameters["learned_stages"])
    return TargetingSetup(config, pose_model, render_model, physical, views, stages, seeds)


def run_prepared_study(setup: TargetingSetup, robot: str) -> tuple[pd.DataFrame, pd.Series]:
    """Run the study on ``robot`` (``"sim"``, ``"rtde"`` or ``"both"``) keeping the volumes; returns
    the records (one row per experiment and robot) and, apart, their volumes for the figures."""
    records = run_targeting_study(setup.config, pose_model=setup.pose_model, render_model=setup.render_model,
                                  physical=setup.physical, views=setup.views, seed=setup.seeds.study, robot=robot,
                                  keep_volumes=True, segmenter=setup.stages.segmenter,
                                  orientation=setup.stages.orientation)
    volumes = records.pop("_volumes")
    return records, volumes


def stand_ins(robot: str, learned_stages: bool, bubble_offset_mm) -> list[tuple[str, str]]:
    """``(lab, synthetic)``: what in this synthetic study stands in for what the paper had in the lab."""
    out = [("manual annotation of the treated zone in the post-treatment CBCT",
            "automatic zone segmentation (local layer variance, histostudy.treatment.zone.segment_treatment_zone)"),
           ("the layered agarose-barium phantom and its CBCTs",
            "the simulated 4 mm layered phantom, mixed inside the union of bubble clouds; Gaussian blur and noise"),
           ("the UR5e", "SimulatedUR5e in process, and the simulated UR controller driven through the real "
            "ur_rtde client (RTDERobot)" if robot == "both" else "SimulatedUR5e in process"),
           ("the cart position and the transducer mount (unknown in the lab)",
            "drawn per experiment: base 500-650 mm from the isocentre, focal point 200-300 mm below the flange, "
            "mounting error 2 mm / 1° SD")]
    if learned_stages:
        out.append(("U-Net segmentation and VGG19 orientation of the calibration frames",
                    "the shipped CPU-trained U-Net and VGG19 (data/models) on the synthetic frames"))
    else:
        out.append(("U-Net segmentation and VGG19 orientation of the calibration frames",
                    "the reference labels degraded to Table I, the true angles with the paper's errors"))
    out.append(("the bubble cloud", "3x3x6 mm ellipsoids at the physical transducer's focal point plus "
                f"{list(bubble_offset_mm)} mm (transducer frame)"))
    return out


def closing_text(n_experiments: int, setup: TargetingSetup, bubble_offset_mm) -> str:
    """The section's closing paragraph: the experiments run, the physical transducer's focal-point
    offset from the digital model's (mm), the bubble offset and the calibration treatment."""
    return (f"{n_experiments} experiment(s). The physical transducer's focal point lies "
            f"{np.linalg.norm(setup.physical.focal_point_mm):.2f} mm from the digital model's; the bubble offset is "
            f"{list(bubble_offset_mm)} mm. The bias correction learns the offset from a calibration treatment of a "
            f"{setup.config.bias_test_diameter_mm:.0f} mm test zone (§IV).")
