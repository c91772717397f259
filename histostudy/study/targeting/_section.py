"""Notebook 05's section: its parameters (:class:`TargetingSectionConfig`), set-up (:func:`prepare`,
every draw from one ``seed``) and parts — the experiments, the calibration, §III's figures, the
calibration sensitivity, the stand-ins — each returning a :class:`~histostudy.study.section.SectionPart`
that :func:`~histostudy.study.section.record` writes (§II-C, §II-D, §III).
"""
from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from histostudy.core import check_count, check_positive, is_finite_real
from histostudy.imaging import View, default_biplane
from histostudy.transducer import TransducerModel, TransducerSpec

from ..pose.experiments import StudyStages, study_stages
from ..section import (
    RenderedSectionConfig,
    SectionPart,
    Timer,
    check_bool,
    check_choice,
    check_splat_device,
    timer_or_untimed,
)
from ._summary import (
    CALIBRATION_TABLE_CAPTION,
    ERROR_TABLE_CAPTION,
    SUMMARY_TABLE_CAPTION,
    calibration_sensitivity_table,
    calibration_table,
    error_table,
    first_robot_rows,
    robot_max_difference,
    sensitivity_caption,
    summary,
    targeting_comparisons,
)
from .experiment import run_targeting_study
from .setup import TargetingStudyConfig

__all__ = ["RECORDED_PARAMETERS", "ROBOTS", "SECTION_TITLE", "NotebookSeeds", "SensitivitySection", "TargetingRun",
           "TargetingSectionConfig", "TargetingSetup", "calibration_part", "closing_part", "closing_text",
           "experiments_section", "notebook_seeds", "prepare", "prepare_study", "run_prepared_study",
           "sensitivity_section", "stand_ins", "study_config_from_parameters", "targeting_part"]

SECTION_TITLE = "05 · Automated targeting: calibration, positioning, treatment (§II-C, §II-D, §II-E.4, §III)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "splat_device", "pose_spacing_mm",
                       "render_spacing_mm", "background", "n_experiments", "zone_diameters_mm", "n_calibration_poses",
                       "pose_mode", "degradation", "learned_stages", "phantom_voxel_mm", "cbct_voxel_mm",
                       "treatment_spacing_mm", "bubble_offset_mm", "bias_correction", "robot")


#: The robots the study runs on: the simulated UR5e, the simulated controller through ur_rtde, both.
ROBOTS = ("sim", "rtde", "both")


def _numbers(value, name: str, what: str, *, length: int | None = None, check=is_finite_real) -> tuple:
    if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or (length is not None and len(value) != length) \
            or not all(check(v) for v in value):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return tuple(value)


@dataclass(frozen=True)
class TargetingSectionConfig(RenderedSectionConfig):
    """Notebook 05's parameters (its ``parameters`` cell names and documents each), checked; values
    are kept as given, lists as tuples.

    Args:
        photons_per_pixel: dose of the calibration frames, photons per unattenuated pixel (§II-B.2).
        n_splats: splats per model point.
        splat_sigma_mm: splat SD (mm).
        pose_spacing_mm: grid of the digital model the pose is estimated with (mm).
        render_spacing_mm: grid of the models the frames are rendered from (mm).
        background: the scene behind the transducer (``"phantom"``, ``"abdomen"``, ``"mixed"``, ``"none"``).
        splat_device: where the frames are splatted, one of :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        n_experiments: phantom experiments (paper: 6).
        zone_diameters_mm: target sphere diameters drawn per experiment (mm, each in (0, 30]).
        n_calibration_poses: robot poses of the hand-eye calibration (>= 3; paper: 4).
        pose_mode: refinement of the pose estimate (``"paper"`` or ``"fast"``).
        degradation: the oracle segmenter's errors where the learned stages fall short.
        learned_stages: the calibration's pose estimates on the shipped U-Net and VGG19.
        phantom_voxel_mm: grid of the true phantom (mm).
        cbct_voxel_mm: grid of the simulated CBCTs (mm).
        treatment_spacing_mm: treatment lattice spacing (LR, TB, depth; mm).
        bubble_offset_mm: bubble-cloud offset from the physical focal point (transducer frame, mm).
        bias_correction: also run the calibration treatment and the corrected targeting (§IV).
        robot: one of :data:`ROBOTS`.
        n_figure_experiments: experiments shown in Fig. 7 (>= 0).
        sensitivity_poses: robot poses of the calibration-sensitivity Monte-Carlo (each >= 3).
        sensitivity_noise: pose noise pairs (translation SD mm, rotation SD deg).
        sensitivity_trials: Monte-Carlo trials per condition.
        render_3d: render the 3-D scene of the set-up.

    Raises:
        ValueError: a bad value, named with its value and what it must be (the experiments' through
            :class:`~histostudy.study.targeting.setup.TargetingStudyConfig`'s checks).
    """

    NOTEBOOK = "05"
    RECORDED = RECORDED_PARAMETERS

    n_experiments: int
    zone_diameters_mm: tuple
    n_calibration_poses: int
    pose_mode: str
    degradation: str
    learned_stages: bool
    phantom_voxel_mm: float
    cbct_voxel_mm: float
    treatment_spacing_mm: tuple
    bubble_offset_mm: tuple
    bias_correction: bool
    robot: str
    n_figure_experiments: int
    sensitivity_poses: tuple
    sensitivity_noise: tuple
    sensitivity_trials: int
    render_3d: bool

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        put("zone_diameters_mm", _numbers(self.zone_diameters_mm, "zone_diameters_mm", "finite diameters in mm"))
        for name in ("treatment_spacing_mm", "bubble_offset_mm"):
            put(name, _numbers(getattr(self, name), name, "3 finite numbers (mm)", length=3))
        for name in ("pose_spacing_mm", "render_spacing_mm"):
            check_positive(getattr(self, name), name, unit="mm")
        check_count(self.n_experiments, "n_experiments")
        check_count(self.n_calibration_poses, "n_calibration_poses", minimum=3)
        check_count(self.n_figure_experiments, "n_figure_experiments", minimum=0)
        check_count(self.sensitivity_trials, "sensitivity_trials")
        for name in ("learned_stages", "bias_correction", "render_3d"):
            put(name, check_bool(getattr(self, name), name))
        check_choice(self.robot, "robot", ROBOTS)
        check_splat_device(self.splat_device)
        put("sensitivity_poses", _numbers(self.sensitivity_poses, "sensitivity_poses", "integers >= 3 (robot poses)",
                                          check=lambda v: isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                          and v >= 3))
        noise = self.sensitivity_noise
        if isinstance(noise, (str, bytes)) or np.ndim(noise) != 2 or np.shape(noise)[1:] != (2,) \
                or not all(is_finite_real(v) and v >= 0 for pair in noise for v in pair):
            raise ValueError(f"sensitivity_noise must be (translation SD mm, rotation SD deg) pairs of finite numbers "
                             f">= 0, got {noise!r}")
        put("sensitivity_noise", tuple(tuple(pair) for pair in noise))
        self.study_config()  # the experiments' parameters, checked by TargetingStudyConfig

    def study_config(self) -> TargetingStudyConfig:
        """The experiments' parameters these give (:func:`study_config_from_parameters`).

        Returns:
            The :class:`~histostudy.study.targeting.setup.TargetingStudyConfig`.

        Raises:
            ValueError: where its checks refuse a value.
        """
        return study_config_from_parameters(self.recorded())


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


def study_config_from_parameters(parameters: Mapping) -> TargetingStudyConfig:
    """The study's configuration from the notebook's parameters: every entry named as a
    :class:`TargetingStudyConfig` field, lists made tuples (the rest keep the config's defaults)."""
    fields = {f.name for f in dataclasses.fields(TargetingStudyConfig)}
    # TargetingStudyConfig checks each value; they are as the notebook gave them until then
    values: dict[str, Any] = {name: tuple(value) if isinstance(value, list) else value
                              for name, value in parameters.items() if name in fields}
    return TargetingStudyConfig(**values)


@dataclass(frozen=True)
class TargetingSetup:
    """What the notebook's experiments run with: the configuration, the digital model the pose is
    estimated with, the (finer) model frames are rendered from, the physical transducer, the
    biplane views, the pose-estimation stages, the seeds and (from :func:`prepare`) the notebook's
    checked ``params``."""

    config: TargetingStudyConfig
    pose_model: TransducerModel
    render_model: TransducerModel
    physical: TransducerModel
    views: Sequence[View]
    stages: StudyStages
    seeds: NotebookSeeds
    params: TargetingSectionConfig | None = None


def _section_params(setup: TargetingSetup) -> TargetingSectionConfig:
    """``setup.params``, which the notebook's parts read; ValueError where a set-up has none (made by
    :func:`prepare_study`, not :func:`prepare`)."""
    if setup.params is None:
        raise ValueError("setup.params is None: expected notebook 05's checked parameters (a TargetingSetup made by "
                         "prepare)")
    return setup.params


def prepare(params: TargetingSectionConfig | Mapping, seed: int, *, timer: Timer | None = None) -> TargetingSetup:
    """The section's set-up (:func:`prepare_study`) from its checked parameters.

    Args:
        params: a :class:`TargetingSectionConfig`, or a mapping naming its fields (the notebook's
            ``globals()``).
        seed: the notebook's root seed (:func:`notebook_seeds`).
        timer: ``timer(name)`` -> a context manager timing the model build (``SectionWriter.timer``);
            None: untimed.

    Returns:
        The :class:`TargetingSetup`, keeping ``params``.

    Raises:
        ValueError: a parameter missing or refused (:class:`TargetingSectionConfig`).
    """
    if not isinstance(params, TargetingSectionConfig):
        params = TargetingSectionConfig.from_parameters(params)
    return dataclasses.replace(prepare_study(params.recorded(), seed, timer=timer), params=params)


def prepare_study(parameters: Mapping, seed: int, *, timer: Timer | None = None) -> TargetingSetup:
    """Build the models (``pose_spacing_mm``, ``render_spacing_mm``; the physical transducer drawn
    from the seed), the default biplane views, the configuration and the stages
    (:func:`~histostudy.study.pose.experiments.study_stages` with ``learned_stages``) from the notebook's
    parameters (a mapping naming at least :data:`RECORDED_PARAMETERS`; :func:`prepare` checks them
    first). ``timer(name)``: a context manager timing the model build (e.g.
    ``SectionWriter.timer``)."""
    seeds = notebook_seeds(seed)
    spec = TransducerSpec()
    with (timer or (lambda name: contextlib.nullcontext()))("build models"):
        pose_model = TransducerModel.build(spec, spacing_mm=parameters["pose_spacing_mm"])
        render_model = TransducerModel.build(spec, spacing_mm=parameters["render_spacing_mm"])
        physical = TransducerModel.build_physical(spec, spacing_mm=parameters["render_spacing_mm"],
                                                  rng=np.random.default_rng(seeds.physical))
    views = default_biplane()
    config = study_config_from_parameters(parameters)
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


# --- the notebook's parts: tables, values and comparisons for record() ------------------------------


@dataclass(frozen=True, eq=False)
class TargetingRun:
    """The study run (:func:`experiments_section`): its ``records`` (one row per experiment and
    robot), their ``volumes`` (for the figures) and the report's ``part`` (the error table)."""

    records: pd.DataFrame
    volumes: pd.Series
    part: SectionPart


def experiments_section(setup: TargetingSetup, *, timer: Timer | None = None) -> TargetingRun:
    """The study on ``setup.params.robot`` (:func:`run_prepared_study`, timed as ``"targeting study"``).

    Args:
        setup: the section's set-up (:func:`prepare`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`TargetingRun`; its part: the per-experiment errors (table ``targeting_errors``).

    Raises:
        TargetingError: a calibration pose's estimate failed its verdict.
        CalibrationError: a calibration beyond its residual bound.
        ValueError: ``setup`` has no ``params`` (not made by :func:`prepare`).
    """
    with timer_or_untimed(timer)("targeting study"):
        records, volumes = run_prepared_study(setup, _section_params(setup).robot)
    return TargetingRun(records, volumes, SectionPart(tables={"targeting_errors": (error_table(records),
                                                                                   ERROR_TABLE_CAPTION)}))


def calibration_part(records: pd.DataFrame) -> SectionPart:
    """The calibration against the ground truth.

    Args:
        records: the study's rows (:attr:`TargetingRun.records`).

    Returns:
        The part: table ``calibration`` (residuals and errors, mm and deg).
    """
    return SectionPart(tables={"calibration": (calibration_table(records), CALIBRATION_TABLE_CAPTION)})


def targeting_part(records: pd.DataFrame) -> SectionPart:
    """§III's targeting figures beside the paper's (:func:`~._summary.targeting_comparisons`).

    Args:
        records: the study's rows (:attr:`TargetingRun.records`).

    Returns:
        The part: table "targeting_summary" (mm), the comparisons and, with both robots, their
        largest difference (value ``rtde_vs_sim_max_difference``, mm).

    Raises:
        ValueError: ``records`` is empty.
    """
    max_difference = robot_max_difference(records)
    return SectionPart(tables={"targeting_summary": (summary(records), SUMMARY_TABLE_CAPTION)},
                       values={} if max_difference is None else {"rtde_vs_sim_max_difference": max_difference},
                       comparisons=tuple(targeting_comparisons(records)))


@dataclass(frozen=True, eq=False)
class SensitivitySection:
    """The calibration-sensitivity Monte-Carlo (:func:`sensitivity_section`): its ``table`` of
    medians and the report's ``part``."""

    table: pd.DataFrame
    part: SectionPart


def sensitivity_section(setup: TargetingSetup, *, timer: Timer | None = None) -> SensitivitySection:
    """Beyond the paper: the hand-eye calibration's median errors over a Monte-Carlo
    (:func:`~._summary.calibration_sensitivity_table` on ``setup.params``' poses, noise and trials,
    timed as ``"calibration sensitivity"``).

    Args:
        setup: the section's set-up (:func:`prepare`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`SensitivitySection`; its part: table ``calibration_sensitivity`` (deg, mm) and
        its rows as value ``calibration_sensitivity_medians``.

    Raises:
        ValueError: ``setup`` has no ``params`` (not made by :func:`prepare`).
    """
    p = _section_params(setup)
    with timer_or_untimed(timer)("calibration sensitivity"):
        table = calibration_sensitivity_table(p.sensitivity_poses, p.sensitivity_noise, p.sensitivity_trials,
                                              setup.seeds.sensitivity)
    return SensitivitySection(table, SectionPart(
        tables={"calibration_sensitivity": (table, sensitivity_caption(p.sensitivity_trials))},
        values={"calibration_sensitivity_medians": table.to_dict("records")}))


def closing_part(setup: TargetingSetup, records: pd.DataFrame) -> SectionPart:
    """What stands in for the lab (:func:`stand_ins`) and the closing paragraph (:func:`closing_text`).

    Args:
        setup: the section's set-up (:func:`prepare`).
        records: the study's rows (:attr:`TargetingRun.records`).

    Returns:
        The part: its stand-ins and one paragraph.

    Raises:
        ValueError: ``setup`` has no ``params`` (not made by :func:`prepare`).
    """
    p = _section_params(setup)
    return SectionPart(stand_ins=tuple(stand_ins(p.robot, setup.stages.learned, p.bubble_offset_mm)),
                       texts=(closing_text(len(first_robot_rows(records)), setup, p.bubble_offset_mm),))
