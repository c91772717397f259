"""Notebook 04's section: its parameters (:class:`PoseSectionConfig`), set-up (:func:`prepare`) and
parts — the experiments, the CBCT reference, Table II beside the paper, the modes and maps, Fig. 6's
pose, the sweeps, the learned stages, RTK's projector, the stand-ins — each a pure function
returning a :class:`~histostudy.study.section.SectionPart` that :func:`~histostudy.study.section.record`
writes. Errors in mm (C-arm frame, depth/TB/LR of §II-E), times in s.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from histostudy.imaging import View, default_biplane, random_background, render_frame, rtk_available
from histostudy.learning import OracleOrientation
from histostudy.pose import estimate_pose
from histostudy.transducer import TransducerModel, TransducerSpec

from ..section import RenderedSectionConfig, SectionPart, Timer, check_splat_device, timer_or_untimed
from . import _projectors as projectors
from ._report_tables import (
    RECORD_COLUMNS,
    REFERENCE_TABLE_COLUMNS,
    failed_estimates,
    focal_error_per_dose,
    focal_error_per_level,
    init_success_comparisons,
    stages_comparison_table,
    table2_beside_paper,
    table2_both_references,
    table2_comparisons,
)
from ._robustness import robustness_summary, robustness_sweep
from ._sweeps import degradation_sweep, noise_sweep
from .experiments import PoseStudyConfig, StudyStages, run_pose_study, study_stages
from .geometry import experiment_pose
from .metrics import (
    experiment_metrics,
    mean_sd,
    reference_error_summary,
    stage_timing,
    table2,
    tracking_summary,
    variant_summary,
)
from .reference import cbct_reference

__all__ = ["SECTION_TITLE", "PoseOverlay", "PoseReference", "PoseRun", "PoseSectionConfig", "PoseSeeds", "PoseSetup",
           "PoseTable", "cbct_reference_part", "closing_part", "degradation_part", "experiments_part",
           "learned_stages_part", "pose_overlay", "pose_seeds", "prepare", "projector_part", "robustness_part",
           "table2_part", "variants_part"]

SECTION_TITLE = "04 · Transducer pose estimation from biplane fluoroscopy (§II-B.3, §II-B.4, §III, Table II)"


@dataclass(frozen=True)
class PoseSectionConfig(RenderedSectionConfig):
    """Notebook 04's parameters, as its parameters cell and the profiles
    (``histostudy/reporting/profiles/*.toml``) name them; values are kept as given.

    Args:
        photons_per_pixel: fluoroscopy dose, Poisson photons per unattenuated pixel (§II-B.2).
        n_splats: splats per model point in the renderer.
        splat_sigma_mm: SD of a splat (mm).
        pose_spacing_mm: point spacing of the digital model the cost uses (mm, §II-B.1).
        render_spacing_mm: point spacing of the rendered and the physical transducer (mm).
        background: the scene behind the transducer (``"phantom"``, ``"abdomen"``, ``"mixed"``).
        splat_device: where the frames are splatted, one of :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        n_experiments: phantom experiments of Table II (paper: 10).
        margin_mm: treatment radii ``r`` drawn per experiment (mm).
        modes: refinement modes (``"paper"``: Nelder-Mead, ``"fast"``: Levenberg-Marquardt).
        distance_maps: distance-map kinds of eq. 3; the first is Table II's.
        degradation: the oracle segmenter's errors (``"table1"`` or ``"none"``).
        robustness_poses: random poses of the initialisation sweep.
        degradation_levels: segmentation degradation levels (0: perfect labels, 1: Table I).
        degradation_poses: poses per degradation level.
        learned_stages: run on the shipped U-Net and VGG19 where they meet the requirements.
        learned_experiments: experiments the other stages (learned or oracle) also run.
        noise_photons: photons per pixel of the dose sweep.
        noise_poses: poses per dose.
        cbct_reference: measure Table II against the simulated post-treatment CBCT, as the paper.
        phantom_voxel_mm: voxel of the true phantom of the CBCT reference (mm).
        cbct_voxel_mm: voxel of the simulated post-treatment CBCT (mm).
        robustness_vgg19: also sweep the random poses with the VGG19 alone as orientation.
        independent_projector: also estimate from frames of RTK's Joseph projector.
        projector_study_poses: study centre poses in the projector comparison.
        projector_random_poses: random poses in the projector comparison.
    """

    NOTEBOOK = "04"

    n_experiments: int
    margin_mm: list
    modes: list
    distance_maps: list
    degradation: str
    robustness_poses: int
    degradation_levels: list
    degradation_poses: int
    learned_stages: bool
    learned_experiments: int
    noise_photons: list
    noise_poses: int
    cbct_reference: bool
    phantom_voxel_mm: float
    cbct_voxel_mm: float
    robustness_vgg19: bool
    independent_projector: bool
    projector_study_poses: int
    projector_random_poses: int

    def __post_init__(self):
        check_splat_device(self.splat_device)

    def study_config(self) -> PoseStudyConfig:
        """The experiments' parameters these give (the rest keep :class:`PoseStudyConfig`'s defaults).

        Returns:
            The :class:`~histostudy.study.pose.experiments.PoseStudyConfig`.

        Raises:
            ValueError: where :class:`PoseStudyConfig`'s checks refuse a value.
        """
        return PoseStudyConfig(
            n_experiments=self.n_experiments, margin_mm=tuple(self.margin_mm), background=self.background,
            photons_per_pixel=self.photons_per_pixel, n_splats=self.n_splats, splat_sigma_mm=self.splat_sigma_mm,
            splat_device=self.splat_device, degradation=self.degradation, modes=tuple(self.modes),
            distance_maps=tuple(self.distance_maps))


@dataclass(frozen=True)
class PoseSeeds:
    """The section's independent seeds (:func:`pose_seeds`).

    Args:
        physical: the physical transducer's manufacturing deviations.
        study: the integer seed of the experiments and the CBCT reference.
        robustness: the robustness sweep's.
        degradation: the degradation sweep's.
        figure: Fig. 6's pose, frames and point subsets.
        noise: the dose sweep's.
    """

    physical: np.random.SeedSequence
    study: int
    robustness: np.random.SeedSequence
    degradation: np.random.SeedSequence
    figure: np.random.SeedSequence
    noise: np.random.SeedSequence


def pose_seeds(seed: int) -> PoseSeeds:
    """The six children of ``SeedSequence(seed)``, in the order of :class:`PoseSeeds`' fields.

    Args:
        seed: the notebook's root seed.

    Returns:
        The :class:`PoseSeeds` (``study`` as the first word of its child's state).
    """
    physical, study, robustness, degradation, figure, noise = np.random.SeedSequence(seed).spawn(6)
    return PoseSeeds(physical, int(study.generate_state(1)[0]), robustness, degradation, figure, noise)


def _sweep_seed(seq: np.random.SeedSequence) -> int:
    return int(seq.generate_state(1)[0])


@dataclass(frozen=True, eq=False)
class PoseSetup:
    """What the section's parts run with (:func:`prepare`).

    Args:
        params: the notebook's checked parameters.
        config: the experiments' parameters (``params.study_config()``).
        pose_model: the digital model the cost uses (``pose_spacing_mm``).
        render_model: the model frames are rendered from (``render_spacing_mm``).
        physical: the physical transducer (its focal point off the digital model's).
        views: the biplane C-arm views.
        stages: the segmenter and orientation source the estimates run on.
        seeds: the section's seeds.
    """

    params: PoseSectionConfig
    config: PoseStudyConfig
    pose_model: TransducerModel
    render_model: TransducerModel
    physical: TransducerModel
    views: Sequence[View]
    stages: StudyStages
    seeds: PoseSeeds

    @property
    def main_maps(self) -> str:
        """The distance-map kind of Table II and the comparisons: the first of the parameters'."""
        return self.params.distance_maps[0]

    @property
    def table_mode(self) -> str:
        """Table II's refinement mode: the paper's (Nelder-Mead) where the profile runs it."""
        return "paper" if "paper" in self.params.modes else self.params.modes[0]

    def models(self) -> dict:
        """The keyword arguments the studies and sweeps take: the three models and the views."""
        return dict(pose_model=self.pose_model, render_model=self.render_model, physical=self.physical,
                    views=self.views)


def prepare(params: PoseSectionConfig | Mapping, seed: int, *, timer: Timer | None = None,
            stages: StudyStages | None = None) -> PoseSetup:
    """The section's set-up: the models built (timed as ``"build models"``; the physical transducer
    from the seeds), the default biplane views, the experiments' config and the stages.

    Args:
        params: a :class:`PoseSectionConfig`, or a mapping naming its fields (the notebook's
            ``globals()``).
        seed: the notebook's root seed (:func:`pose_seeds`).
        timer: ``timer(name)`` -> a context manager (``SectionWriter.timer``); None: untimed.
        stages: the segmenter and orientation source; None: :func:`study_stages` of the
            parameters' ``learned_stages``.

    Returns:
        The :class:`PoseSetup`.

    Raises:
        ValueError: a parameter missing from ``params``, or refused by :class:`PoseStudyConfig`.
    """
    section_config = params if isinstance(params, PoseSectionConfig) else PoseSectionConfig.from_parameters(params)
    seeds = pose_seeds(seed)
    spec = TransducerSpec()
    with (timer or (lambda name: contextlib.nullcontext()))("build models"):
        pose_model = TransducerModel.build(spec, spacing_mm=section_config.pose_spacing_mm)
        render_model = TransducerModel.build(spec, spacing_mm=section_config.render_spacing_mm)
        physical = TransducerModel.build_physical(spec, spacing_mm=section_config.render_spacing_mm,
                                                  rng=np.random.default_rng(seeds.physical))
    views = default_biplane()
    config = section_config.study_config()
    stages = study_stages(config, section_config.learned_stages) if stages is None else stages
    return PoseSetup(section_config, config, pose_model, render_model, physical, views, stages, seeds)


@dataclass(frozen=True, eq=False)
class PoseRun:
    """The experiments of Table II (:func:`experiments_part`).

    Args:
        records: :func:`run_pose_study`'s rows (every estimate).
        metrics: Table II's quantities per experiment against the ground truth.
        failed: the failed estimates (the table the notebook shows).
        part: the report's part.
    """

    records: pd.DataFrame
    metrics: pd.DataFrame
    failed: pd.DataFrame
    part: SectionPart


@dataclass(frozen=True, eq=False)
class PoseReference:
    """The post-treatment CBCT reference (:func:`cbct_reference_part`); each table None where the
    profile disables it.

    Args:
        reference: :func:`cbct_reference`'s table.
        metrics: Table II's quantities per experiment against it.
        errors: the reference's own error against the ground truth (the table the notebook shows).
        part: the report's part.
    """

    reference: pd.DataFrame | None
    metrics: pd.DataFrame | None
    errors: pd.DataFrame | None
    part: SectionPart


@dataclass(frozen=True, eq=False)
class PoseTable:
    """A part and the table the notebook shows of it.

    Args:
        table: the table shown (None where the part did not run).
        part: the report's part.
    """

    table: pd.DataFrame | None
    part: SectionPart


def experiments_part(setup: PoseSetup, *, timer: Timer | None = None) -> PoseRun:
    """The experiments of Table II (:func:`run_pose_study`, timed as ``"pose study"``) and their
    metrics against the ground truth.

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseRun`; its part: tables ``pose_records``, ``experiment_metrics``, values
        ``stages`` and ``failed_estimates``.
    """
    stages = setup.stages
    with timer_or_untimed(timer)("pose study"):
        records = run_pose_study(setup.config, **setup.models(), seed=setup.seeds.study,
                                 segmenter=stages.segmenter, orientation=stages.orientation)
    metrics = experiment_metrics(records)
    failed = failed_estimates(records)
    part = SectionPart(
        tables={"pose_records": (records[RECORD_COLUMNS], "Every estimate: error along depth/TB/LR and Euclidean "
                                 "(mm), rotation error (deg, modulo the half-turn symmetry), refinement iterations, "
                                 "total time (s)"),
                "experiment_metrics": (metrics, "Table II's quantities per experiment, mode and map kind (mm), "
                                       "against the ground truth")},
        values={"stages": stages.why, "failed_estimates": failed.to_dict("records")})
    return PoseRun(records, metrics, failed, part)


def cbct_reference_part(setup: PoseSetup, run: PoseRun, *, timer: Timer | None = None) -> PoseReference:
    """The post-treatment CBCT reference (:func:`cbct_reference`, timed as ``"CBCT reference"``) and
    Table II's metrics against it, where the parameters ask for it.

    Args:
        setup: the section's set-up.
        run: the experiments (:func:`experiments_part`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseReference`; its part: tables ``cbct_reference``, ``experiment_metrics_cbct``,
        ``cbct_reference_error``, the reference's error beside the paper and the failed references
        (``failed_cbct_reference``); or, with ``cbct_reference`` off, a paragraph saying so.
    """
    p = setup.params
    if not p.cbct_reference:
        return PoseReference(None, None, None, SectionPart(texts=(
            "Table II is measured against the ground truth only: the CBCT reference was disabled "
            "(`cbct_reference = False`).",)))
    with timer_or_untimed(timer)("CBCT reference"):
        reference = cbct_reference(setup.config, physical=setup.physical, seed=setup.seeds.study, records=run.records,
                                   phantom_voxel_mm=p.phantom_voxel_mm, cbct_voxel_mm=p.cbct_voxel_mm)
    metrics = experiment_metrics(run.records, reference=reference)
    errors = reference_error_summary(reference)
    failed = reference[~reference["ok"].astype(bool)]
    part = SectionPart(
        tables={"cbct_reference": (reference[REFERENCE_TABLE_COLUMNS], "The post-treatment CBCT reference per "
                                   "experiment: segmented centroid minus true bubble-cloud centre along depth/TB/LR "
                                   "and Euclidean, zone radii along depth/TB/LR, fitted sphere radius, clearance of "
                                   "the sphere from the phantom's faces (mm)"),
                "experiment_metrics_cbct": (metrics, "Table II's quantities per experiment, mode and map kind (mm), "
                                            "against the post-treatment CBCT"),
                "cbct_reference_error": (errors, "The error of the CBCT reference against the ground truth (mean ± SD "
                                         f"over {len(reference)} experiments, mm)")},
        values={"failed_cbct_reference": failed[["experiment", "failure"]].to_dict("records")} if len(failed) else {},
        comparisons=(
            dict(key="pose.cbct_reference_error_mm", label="CBCT reference: segmented centroid vs true bubble-cloud "
                 "centre", ours=mean_sd(reference["ref_err_euclidean"]), unit="mm", paper_key="",
                 note="the error of the reference itself (treatment geometry, CBCT, automatic segmentation)"),
            dict(key="pose.cbct_reference_radius_error_mm", label="CBCT reference: fitted zone radius minus r",
                 ours=mean_sd(reference["sphere_radius_err_mm"]), unit="mm", paper_key="",
                 note="signed: negative = the segmented zone reads small")))
    return PoseReference(reference, metrics, errors, part)


def table2_part(setup: PoseSetup, run: PoseRun, reference: PoseReference, *, paper: Mapping) -> PoseTable:
    """Table II (§III) of :attr:`PoseSetup.table_mode` and :attr:`PoseSetup.main_maps` beside the
    paper's values: against the CBCT reference under the paper's keys ``table2.*`` and against the
    ground truth under ``table2_truth.*`` (the ground truth under ``table2.*`` without the reference).

    Args:
        setup: the section's set-up.
        run: the experiments (:func:`experiments_part`).
        reference: the CBCT reference (:func:`cbct_reference_part`).
        paper: the paper's values by key (:data:`histostudy.reporting.PAPER`).

    Returns:
        The :class:`PoseTable`: both references and the paper in one table; its part: tables
        ``table2`` (and ``table2_truth``), the comparisons with the paper, value ``table2_reference``.

    Raises:
        ValueError: where the metrics hold no row of Table II's mode and maps (:func:`table2`).
    """
    p = setup.params
    table_mode, main_maps = setup.table_mode, setup.main_maps
    table_truth, values_truth = table2(run.metrics, table_mode, main_maps)
    caption = (f"Table II (mm, mean ± SD over {p.n_experiments} experiments): {table_mode} mode, "
               f"{main_maps.replace('_', '-')} maps")
    truth_caption = caption + "; reference = true bubble-cloud centre and sphere of radius r"
    if p.cbct_reference:
        table_cbct, values = table2(reference.metrics, table_mode, main_maps)
        tables = {"table2": (table2_beside_paper(table_cbct, paper), caption + "; reference = post-treatment CBCT "
                             "(treated zone segmented automatically), as the paper"),
                  "table2_truth": (table2_beside_paper(table_truth, paper), truth_caption)}
        comparisons = [*table2_comparisons(values, "table2.", "CBCT reference"),
                       *table2_comparisons(values_truth, "table2_truth.", "ground-truth reference"),
                       dict(key="pose.center_euclidean", label="Centre error, Euclidean (CBCT reference)",
                            ours=values["table2.center_mae.overall"], unit="mm"),
                       dict(key="pose.center_euclidean_truth", label="Centre error, Euclidean (ground-truth reference)",
                            ours=values_truth["table2.center_mae.overall"], unit="mm",
                            paper_key="pose.center_euclidean")]
        reference_name, shown = "cbct", table2_both_references(table_cbct, table_truth, paper)
    else:
        values = values_truth
        tables = {"table2": (table2_beside_paper(table_truth, paper), truth_caption)}
        comparisons = [*table2_comparisons(values, "table2.", "ground-truth reference"),
                       dict(key="pose.center_euclidean", label="Centre error, Euclidean (ground-truth reference)",
                            ours=values["table2.center_mae.overall"], unit="mm")]
        reference_name, shown = "truth", table2_beside_paper(table_truth, paper)
    comparisons += [dict(key="pose.precision_mm", label="Precision: centroid of the six margin predictions vs centre "
                         "prediction", ours=values["pose.precision"], unit="mm", paper_key="",
                         note="§II-E.3 defines it; §III gives no number"),
                    dict(key="pose.n_studies", label="Pose-estimation experiments", ours=p.n_experiments)]
    return PoseTable(shown, SectionPart(tables=tables, values={"table2_reference": reference_name},
                                        comparisons=tuple(comparisons)))


def variants_part(setup: PoseSetup, run: PoseRun) -> PoseTable:
    """Beyond the paper: the refinement modes and distance maps side by side, time per stage and
    warm-start tracking.

    Args:
        setup: the section's set-up.
        run: the experiments (:func:`experiments_part`).

    Returns:
        The :class:`PoseTable`: the median seconds per stage (rounded to 3 decimals); its part:
        tables ``variants``, ``stage_timing``, value ``tracking`` and the timing comparisons.
    """
    summary = variant_summary(run.metrics)
    timing = stage_timing(run.records)
    tracking = tracking_summary(run.records)
    comparisons = []
    fast = timing[(timing["mode"] == "fast") & (timing["maps"] == setup.main_maps)]
    if len(fast):
        comparisons.append(dict(key="pose.seconds_from_scratch", label="Pose from scratch (init + refine), fast mode",
                                ours=float(fast["initialisation"].iloc[0] + fast["refinement"].iloc[0]), unit="s",
                                paper_key="", note="target ≤ 1 s on 2 cores; the paper ran CUDA and gave no time"))
    if tracking:
        comparisons += [dict(key="pose.seconds_tracking_refine", label="Warm-start tracking refinement (median)",
                             ours=tracking["track_refinement_s"], unit="s", digits=3, paper_key="",
                             note="target ≤ 50 ms"),
                        dict(key="pose.tracking_error_mm", label="Warm-start tracking, focal error",
                             ours=tracking["track_error_mm"], unit="mm", paper_key="")]
    part = SectionPart(
        tables={"variants": (summary, "Centre error, radius MAE and precision per refinement mode and map kind (mm), "
                             "against the ground truth"),
                "stage_timing": (timing, "Median seconds per stage of estimate_pose (2-core CPU, "
                                 f"{'learned' if setup.stages.learned else 'oracle'} stages"
                                 + ("; the U-Net segments an acquisition's frames once, in its first variant's "
                                    "time)" if setup.stages.learned else ")"))},
        values={"tracking": tracking}, comparisons=tuple(comparisons))
    return PoseTable(timing.round(3), part)


@dataclass(frozen=True, eq=False)
class PoseOverlay:
    """Fig. 6's pose (:func:`pose_overlay`).

    Args:
        frames: the biplane frames of the true pose.
        T_true: the true pose ``T_carm_transducer`` (4x4, mm; transducer -> C-arm).
        T_carm_transducer: the estimated pose (4x4, mm; transducer -> C-arm).
        focal_error_mm: the estimate's focal-point error against the physical transducer's (mm).
        caption: the figure's caption.
        rng: the stream the figure draws its point subsets from.
    """

    frames: list
    T_true: np.ndarray
    T_carm_transducer: np.ndarray
    focal_error_mm: float
    caption: str
    rng: np.random.Generator


def pose_overlay(setup: PoseSetup) -> PoseOverlay:
    """Fig. 6's pose: a fresh experiment pose (its own seed) rendered and estimated in
    :attr:`PoseSetup.table_mode` with :attr:`PoseSetup.main_maps`; the notebook draws it
    (:func:`histostudy.reporting.plot_pose_overlay`) with the returned ``rng``.

    Args:
        setup: the section's set-up.

    Returns:
        The :class:`PoseOverlay` (a failed verdict is named in its caption, not raised).
    """
    p, config = setup.params, setup.config
    rng_fig = np.random.default_rng(setup.seeds.figure)
    scene = random_background(rng_fig, p.background)
    T_true = experiment_pose(rng_fig, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
    frames = [render_frame(setup.render_model, T_true, v, rng=rng_fig, physical=setup.physical, background=scene,
                           **config.frame_kwargs()) for v in setup.views]
    result = estimate_pose(frames, setup.pose_model, segmenter=setup.stages.segmenter,
                           orientation=setup.stages.orientation, rng=rng_fig, mode=setup.table_mode,
                           distance_maps=setup.main_maps, raise_on_failure=False)
    focal_error = np.linalg.norm(result.focal_point_mm
                                 - (T_true[:3, :3] @ setup.physical.focal_point_mm + T_true[:3, 3]))
    verdict = "" if result.verdict.ok else " — failed verdict: " + "; ".join(result.verdict.reasons)
    caption = (f"Fig. 6 (columns 1-2): X-ray and the digital model in the estimated pose "
               f"(focal error {focal_error:.2f} mm{verdict})")
    return PoseOverlay(frames, T_true, result.T_carm_transducer, float(focal_error), caption, rng_fig)


def robustness_part(setup: PoseSetup, *, timer: Timer | None = None) -> PoseTable:
    """Beyond the paper: initialisation success over random poses (:func:`robustness_sweep`, timed as
    ``"robustness sweep"``) with the oracle stages (both initialisations) and, where the study runs
    on them, the learned ones (and, with ``robustness_vgg19``, the VGG19 alone as orientation).

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseTable`: the success per stages and initialisation; its part: tables
        ``robustness``, ``robustness_summary`` and the success comparisons.
    """
    p, stages = setup.params, setup.stages
    sweep = dict(**setup.models(), seed=_sweep_seed(setup.seeds.robustness), config=setup.config)
    # every set on each pose's frames, rendered once (the rows those of a sweep per set)
    sets: dict[str, dict[str, object]] = {"oracle": {}}
    if stages.learned:
        sets["learned"] = dict(inits=("robust",), segmenter=stages.segmenter, orientation=stages.orientation)
        vgg19 = getattr(stages.orientation, "fallback", None)
        if p.robustness_vgg19 and vgg19 is not None:
            sets["learned-vgg19"] = dict(inits=("robust",), segmenter=stages.segmenter, orientation=vgg19)
    with timer_or_untimed(timer)("robustness sweep"):
        robust = robustness_sweep(p.robustness_poses, **sweep, stage_sets=sets)
        # the table as before: a set's rows together, the sets in order
        robust = robust.sort_values("stages", key=lambda s: s.map(list(sets).index), kind="stable",
                                    ignore_index=True)
    rates = robustness_summary(robust, by=("stages", "init"))
    part = SectionPart(
        tables={"robustness": (robust, "Initialisation over random poses: error (mm), verdict, time (s)"),
                "robustness_summary": (rates, "Initialisation over random poses per stages and method: success "
                                       "(< 2 mm), refused by the verdict, accepted although off by 2 mm or more",
                                       {"digits": 3})},
        comparisons=tuple(init_success_comparisons(rates)))
    return PoseTable(rates, part)


def degradation_part(setup: PoseSetup, *, timer: Timer | None = None) -> PoseTable:
    """Beyond the paper: focal error vs segmentation degradation (:func:`degradation_sweep`, timed
    as ``"degradation sweep"``).

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseTable`: the focal error per level; its part: table ``degradation``.

    Raises:
        ValueError: a level that would take a class's recall to 0 or below.
    """
    p = setup.params
    with timer_or_untimed(timer)("degradation sweep"):
        degrade = degradation_sweep(p.degradation_levels, **setup.models(), seed=_sweep_seed(setup.seeds.degradation),
                                    config=setup.config, n_poses=p.degradation_poses)
    per_level = focal_error_per_level(degrade)
    return PoseTable(per_level, SectionPart(tables={"degradation": (per_level, "Focal error vs segmentation "
                                                                                 "degradation (fast mode)")}))


def learned_stages_part(setup: PoseSetup, run: PoseRun, *, timer: Timer | None = None) -> PoseTable:
    """The shipped learned stages beside the oracles on the same frames of the first
    ``learned_experiments`` experiments (whichever the study did not run is run here, timed as
    ``"pose study, <other> stages (comparison)"``), and the focal error vs dose with the learned
    stages (timed as ``"noise sweep"``).

    Args:
        setup: the section's set-up.
        run: the experiments (:func:`experiments_part`).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseTable`: the comparison (None without usable shipped networks); its part:
        tables ``learned_vs_oracle``, ``noise``, value ``learned_manifests`` and the comparison, or a
        paragraph saying why the stages were not run.
    """
    p, stages, records = setup.params, setup.stages, run.records
    unet, vgg = stages.shipped_segmenter, stages.shipped_orientation
    if unet is None or vgg is None:
        return PoseTable(None, SectionPart(texts=(
            "The learned stages were not run: " + ("disabled by the profile." if not p.learned_stages else
                                                   "no usable shipped U-Net and VGG19 in data/models (see notebooks "
                                                   "02 and 03)."),)))
    compare_mode = "fast" if "fast" in p.modes else p.modes[0]
    compare_config = replace(setup.config, n_experiments=min(p.learned_experiments, p.n_experiments),
                             modes=(compare_mode,), distance_maps=(setup.main_maps,), track=False)
    main_rows = records[(records["mode"] == compare_mode) & (records["maps"] == setup.main_maps)
                        & (records["experiment"] < compare_config.n_experiments)]
    other = "oracle" if stages.learned else "learned"
    timed = timer_or_untimed(timer)
    with timed(f"pose study, {other} stages (comparison)"):
        other_rows = run_pose_study(
            compare_config, **setup.models(), seed=setup.seeds.study,
            segmenter=setup.config.segmenter() if stages.learned else unet,
            orientation=OracleOrientation() if stages.learned else vgg)
    learned, oracle = (main_rows, other_rows) if stages.learned else (other_rows, main_rows)
    both = stages_comparison_table(learned, oracle)
    with timed("noise sweep"):
        noise = noise_sweep(p.noise_photons, **setup.models(), seed=_sweep_seed(setup.seeds.noise),
                            config=setup.config, segmenter=unet, orientation=vgg, n_poses=p.noise_poses)
    part = SectionPart(
        tables={"learned_vs_oracle": (both, "Focal error with the learned stages and with the oracles, same frames"),
                "noise": (focal_error_per_dose(noise), "Focal error vs photons per pixel (learned stages, fast mode)")},
        values={"learned_manifests": {"unet": (getattr(unet, "manifest", None) or {}).get("weights_file"),
                                      "vgg19": (getattr(vgg, "manifest", None) or {}).get("weights_file")}},
        comparisons=(dict(key="pose.learned_minus_oracle_mm", label="Mean focal error, learned minus oracle stages",
                          ours=float(learned["err_euclidean"].mean() - oracle["err_euclidean"].mean()), unit="mm",
                          paper_key="", note="target ≤ 0.1 mm"),))
    return PoseTable(both, part)


def projector_part(setup: PoseSetup, *, timer: Timer | None = None) -> PoseTable:
    """Beyond the paper: the same poses from the splatting renderer and RTK's Joseph projector
    (timed as ``"projector comparison, <n> poses"``), where the parameters ask and itk-rtk is installed.

    Args:
        setup: the section's set-up.
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`PoseTable`: the summary per pose kind and projector (None where not run); its
        part: tables "projector_comparison", "projector_summary" and the RTK-minus-splatting
        comparisons, or a paragraph saying why it was not run.
    """
    p, stages = setup.params, setup.stages
    if not p.independent_projector:
        return PoseTable(None, SectionPart(texts=(
            "The independent projector was not run (independent_projector = False in this profile).",)))
    if not rtk_available():
        return PoseTable(None, SectionPart(texts=(
            "The independent projector was not run: itk-rtk is not installed (pip install 'histostudy[rtk]').",)))
    poses = projectors.comparison_poses(setup.config, setup.seeds.study, n_study=p.projector_study_poses,
                                        n_random=p.projector_random_poses, views=setup.views,
                                        pose_model=setup.pose_model)
    with timer_or_untimed(timer)(f"projector comparison, {len(poses)} poses"):
        projected = projectors.projector_comparison(poses, **setup.models(), config=setup.config,
                                                    seed=setup.seeds.study, segmenter=stages.segmenter,
                                                    orientation=stages.orientation)
    summary = projectors.projector_summary(projected)
    comparisons = tuple(
        dict(key=f"pose.projector_difference.{row.kind}", label=f"RTK minus splatting, mean focal error ({row.kind} "
             "poses)", ours=row.paired_difference_mm, unit="mm", digits=3, paper_key="",
             note=f"{stages.why.split(':')[0]}; target within ± 0.1 mm")
        for row in summary[summary["projector"] == "rtk-joseph"].itertuples())
    part = SectionPart(
        tables={"projector_comparison": (projected, "Focal error (mm) per pose and projector, verdict, seconds"),
                "projector_summary": (summary, "Splatting renderer vs RTK Joseph projector, same poses: accepted "
                                      "estimates' focal error (mm), refusals, wrong acceptances, paired difference "
                                      "(mm)", {"digits": 3})},
        comparisons=comparisons)
    return PoseTable(summary, part)


def closing_part(setup: PoseSetup, run: PoseRun) -> SectionPart:
    """What stands in for the lab's treatment, CBCT, networks and robot, and the closing paragraph.

    Args:
        setup: the section's set-up.
        run: the experiments (:func:`experiments_part`).

    Returns:
        The part: its stand-ins and one paragraph.
    """
    p, records = setup.params, run.records
    if p.cbct_reference:
        stand_ins = [("treatment, post-treatment CBCT and manual segmentation of the treated zone (reference)",
                      "the treatment simulated about the true centre pose (notebook 05's plan, 3x3x6 mm bubble clouds "
                      "at the physical focal point, the layered phantom mixed), a simulated CBCT (0.5 mm blur, 20 HU "
                      f"noise, {p.cbct_voxel_mm} mm voxels) and the automatic zone segmentation; the ground truth "
                      "(true bubble-cloud centre, sphere of radius r) reported beside it")]
    else:
        stand_ins = [("post-treatment CBCT, manual segmentation of the treated zone (reference)",
                      "the true bubble-cloud centre (physical focal point in the true pose) and the sphere of "
                      "radius r")]
    if not setup.stages.learned:
        stand_ins += [("U-Net segmentation (§II-B.2)", "the reference labels degraded to Table I's per-class precision "
                       "and recall (" + setup.stages.why + ")"),
                      ("VGG19 azimuth/elevation (§II-B.4)", "the true angles plus Gaussian errors with the paper's "
                       "MAE")]
    stand_ins.append(("UR5e moves of 10/12.5 mm along its axes", "exact moves along the transducer's LR/TB/depth axes "
                      "plus 0.01 mm SD positioning noise"))
    ok = records["ok"].astype(bool)
    text = (f"{len(records)} pose estimates, {int((~ok).sum())} with a failed verdict (listed in "
            f"`failed_estimates`). Table II is measured against "
            + ("the post-treatment CBCT (as the paper) and against " if p.cbct_reference else "")
            + f"the physical transducer's focal point, which differs from the digital model's by "
            f"{np.linalg.norm(setup.physical.focal_point_mm):.2f} mm (manufacturing deviation), the kind of "
            "bias §IV attributes to model mismatch.")
    return SectionPart(texts=(text,), stand_ins=tuple(stand_ins))
