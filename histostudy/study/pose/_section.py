"""Notebook 04's report section, part by part: Table II (§III) and what the paper's §II-D, §II-E.3 imply.

:class:`PoseSection` runs each part of the notebook — the experiments, the post-treatment CBCT
reference, Table II beside the paper's values, the modes and maps, the Fig. 6 overlay, the
robustness, degradation and dose sweeps, the learned stages beside the oracles, the independent
projector — and records it through the section's writer
(:class:`histostudy.reporting.SectionWriter`, passed in: the study layer does not import the
reporting layer); :mod:`~histostudy.study.pose._report_tables` shapes its tables. Errors in mm
(C-arm frame, along the transducer's depth/TB/LR axes of §II-E), times in s.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from histostudy.imaging import default_biplane, random_background, render_frame, rtk_available
from histostudy.learning import OracleOrientation
from histostudy.pose import estimate_pose
from histostudy.transducer import TransducerModel, TransducerSpec

from . import _projectors as projectors
from ._config import PoseSectionConfig, StudyStages, study_stages
from ._experiments import run_pose_study
from ._geometry import experiment_pose
from ._metrics import (
    experiment_metrics,
    mean_sd,
    reference_error_summary,
    stage_timing,
    table2,
    tracking_summary,
    variant_summary,
)
from ._reference import cbct_reference
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

__all__ = ["PoseOverlay", "PoseSection"]


@dataclass(frozen=True, eq=False)
class PoseOverlay:
    """Fig. 6's pose: the biplane ``frames`` of a true pose ``T_true`` (C-arm frame, mm), the
    estimated ``T_carm_transducer``, its ``focal_error_mm``, the figure's ``caption``, and ``rng``,
    the stream the figure draws its point subsets from."""

    frames: list
    T_true: np.ndarray
    T_carm_transducer: np.ndarray
    focal_error_mm: float
    caption: str
    rng: np.random.Generator


def _written_once(part):
    """A :class:`PoseSection` part that runs once: a second call returns the first call's result."""
    @functools.wraps(part)
    def once(self):
        if part.__name__ not in self._written:
            self._written[part.__name__] = part(self)
        return self._written[part.__name__]
    return once


class PoseSection:
    """Notebook 04's section: builds the models and the study set-up, then writes one part per call.

    Each part returns the table the notebook shows, in any order: a part that reads the
    experiments' records (or the CBCT reference) runs :meth:`run_experiments` (or
    :meth:`write_cbct_reference`) first where it has not run yet, and a part called twice returns
    what it wrote the first time without writing it again. ``writer``:
    a :class:`histostudy.reporting.SectionWriter`; ``paper``: :data:`histostudy.reporting.PAPER`.
    ``stages``: the segmenter and orientation source (default :func:`study_stages` of the
    parameters' ``learned_stages``). Seeds: six children of ``SeedSequence(seed)`` — the physical
    transducer, the study, the robustness sweep, the degradation sweep, Fig. 6, the noise sweep.
    """

    def __init__(self, writer, parameters: PoseSectionConfig, seed: int, *, paper: Mapping,
                 stages: StudyStages | None = None):
        self.writer, self.parameters, self.paper = writer, parameters, paper
        (seed_physical, self.seed_study, self.seed_robust, self.seed_degrade, self.seed_figure,
         self.seed_noise) = np.random.SeedSequence(seed).spawn(6)
        spec = TransducerSpec()
        with writer.timer("build models"):
            self.pose_model = TransducerModel.build(spec, spacing_mm=parameters.pose_spacing_mm)
            self.render_model = TransducerModel.build(spec, spacing_mm=parameters.render_spacing_mm)
            self.physical = TransducerModel.build_physical(spec, spacing_mm=parameters.render_spacing_mm,
                                                           rng=np.random.default_rng(seed_physical))
        self.views = default_biplane()
        self.config = parameters.study_config()
        self.stages = study_stages(self.config, parameters.learned_stages) if stages is None else stages
        self.study_seed = int(self.seed_study.generate_state(1)[0])
        self.records = self.metrics = self.reference = self.metrics_cbct = None
        self._written: dict[str, object] = {}  # part -> what it returned, so that each part writes once

    @property
    def main_maps(self) -> str:
        """The distance-map kind of Table II and the comparisons: the first of the parameters'."""
        return self.parameters.distance_maps[0]

    @property
    def table_mode(self) -> str:
        """Table II's refinement mode: the paper's (Nelder-Mead) where the profile runs it."""
        return "paper" if "paper" in self.parameters.modes else self.parameters.modes[0]

    def _models(self) -> dict:
        return dict(pose_model=self.pose_model, render_model=self.render_model, physical=self.physical,
                    views=self.views)

    def _require_records(self) -> pd.DataFrame:
        if self.records is None:
            self.run_experiments()
        return self.records

    @_written_once
    def run_experiments(self) -> pd.DataFrame:
        """The experiments of Table II (:func:`run_pose_study`) and their metrics against the ground
        truth; records the stages, every estimate and the failures. Returns the failures."""
        writer, stages = self.writer, self.stages
        writer.value("stages", stages.why)
        with writer.timer("pose study"):
            self.records = run_pose_study(self.config, **self._models(), seed=self.study_seed,
                                          segmenter=stages.segmenter, orientation=stages.orientation)
        self.metrics = experiment_metrics(self.records)
        writer.table("pose_records", self.records[RECORD_COLUMNS], "Every estimate: error along depth/TB/LR and "
                     "Euclidean (mm), rotation error (deg, modulo the half-turn symmetry), refinement iterations, "
                     "total time (s)")
        writer.table("experiment_metrics", self.metrics, "Table II's quantities per experiment, mode and map kind "
                     "(mm), against the ground truth")
        failed = failed_estimates(self.records)
        writer.value("failed_estimates", failed.to_dict("records"))
        return failed

    @_written_once
    def write_cbct_reference(self) -> pd.DataFrame | None:
        """The post-treatment CBCT reference (:func:`cbct_reference`) and Table II's metrics against
        it; returns the reference's own error (None where the profile disables it)."""
        writer, p, records = self.writer, self.parameters, self._require_records()
        if not p.cbct_reference:
            writer.text("Table II is measured against the ground truth only: the CBCT reference was disabled "
                        "(`cbct_reference = False`).")
            return None
        with writer.timer("CBCT reference"):
            self.reference = reference = cbct_reference(
                self.config, physical=self.physical, seed=self.study_seed, records=records,
                phantom_voxel_mm=p.phantom_voxel_mm, cbct_voxel_mm=p.cbct_voxel_mm)
        self.metrics_cbct = experiment_metrics(records, reference=reference)
        writer.table("cbct_reference", reference[REFERENCE_TABLE_COLUMNS], "The post-treatment CBCT reference per "
                     "experiment: segmented centroid minus true bubble-cloud centre along depth/TB/LR and Euclidean, "
                     "zone radii along depth/TB/LR, fitted sphere radius, clearance of the sphere from the phantom's "
                     "faces (mm)")
        writer.table("experiment_metrics_cbct", self.metrics_cbct, "Table II's quantities per experiment, mode and "
                     "map kind (mm), against the post-treatment CBCT")
        reference_errors = reference_error_summary(reference)
        writer.table("cbct_reference_error", reference_errors, "The error of the CBCT reference against the ground "
                     f"truth (mean ± SD over {len(reference)} experiments, mm)")
        writer.compare("pose.cbct_reference_error_mm", "CBCT reference: segmented centroid vs true bubble-cloud centre",
                       mean_sd(reference["ref_err_euclidean"]), unit="mm", paper_key="",
                       note="the error of the reference itself (treatment geometry, CBCT, automatic segmentation)")
        writer.compare("pose.cbct_reference_radius_error_mm", "CBCT reference: fitted zone radius minus r",
                       mean_sd(reference["sphere_radius_err_mm"]), unit="mm", paper_key="",
                       note="signed: negative = the segmented zone reads small")
        failed_reference = reference[~reference["ok"].astype(bool)]
        if len(failed_reference):
            writer.value("failed_cbct_reference", failed_reference[["experiment", "failure"]].to_dict("records"))
        return reference_errors

    @_written_once
    def write_table2(self) -> pd.DataFrame:
        """Table II of :attr:`table_mode` and :attr:`main_maps` beside the paper's values: against the
        CBCT reference under the paper's keys ``table2.*`` and against the ground truth under
        ``table2_truth.*`` (the ground truth under ``table2.*`` without the CBCT reference). Returns
        the table shown: both references and the paper in one."""
        writer, p, paper = self.writer, self.parameters, self.paper
        self._require_records()
        self.write_cbct_reference()
        table_mode, main_maps = self.table_mode, self.main_maps
        table_truth, values_truth = table2(self.metrics, table_mode, main_maps)
        caption = (f"Table II (mm, mean ± SD over {p.n_experiments} experiments): {table_mode} mode, "
                   f"{main_maps.replace('_', '-')} maps")
        if p.cbct_reference:
            table_cbct, values = table2(self.metrics_cbct, table_mode, main_maps)
            writer.table("table2", table2_beside_paper(table_cbct, paper), caption + "; reference = post-treatment "
                         "CBCT (treated zone segmented automatically), as the paper")
            writer.table("table2_truth", table2_beside_paper(table_truth, paper), caption + "; reference = true "
                         "bubble-cloud centre and sphere of radius r")
            for comparison in (table2_comparisons(values, "table2.", "CBCT reference")
                               + table2_comparisons(values_truth, "table2_truth.", "ground-truth reference")):
                writer.compare(**comparison)
            writer.compare("pose.center_euclidean", "Centre error, Euclidean (CBCT reference)",
                           values["table2.center_mae.overall"], unit="mm")
            writer.compare("pose.center_euclidean_truth", "Centre error, Euclidean (ground-truth reference)",
                           values_truth["table2.center_mae.overall"], unit="mm", paper_key="pose.center_euclidean")
            writer.value("table2_reference", "cbct")
            shown = table2_both_references(table_cbct, table_truth, paper)
        else:
            values = values_truth
            writer.table("table2", table2_beside_paper(table_truth, paper), caption + "; reference = true "
                         "bubble-cloud centre and sphere of radius r")
            for comparison in table2_comparisons(values, "table2.", "ground-truth reference"):
                writer.compare(**comparison)
            writer.compare("pose.center_euclidean", "Centre error, Euclidean (ground-truth reference)",
                           values["table2.center_mae.overall"], unit="mm")
            writer.value("table2_reference", "truth")
            shown = table2_beside_paper(table_truth, paper)
        writer.compare("pose.precision_mm", "Precision: centroid of the six margin predictions vs centre prediction",
                       values["pose.precision"], unit="mm", paper_key="", note="§II-E.3 defines it; §III gives no number")
        writer.compare("pose.n_studies", "Pose-estimation experiments", p.n_experiments)
        return shown

    @_written_once
    def write_variants(self) -> pd.DataFrame:
        """Beyond the paper: the refinement modes and distance maps side by side, time per stage and
        warm-start tracking. Returns the median seconds per stage."""
        writer, records = self.writer, self._require_records()
        summary = variant_summary(self.metrics)
        writer.table("variants", summary, "Centre error, radius MAE and precision per refinement mode and map kind "
                     "(mm), against the ground truth")
        timing = stage_timing(records)
        writer.table("stage_timing", timing, "Median seconds per stage of estimate_pose (2-core CPU, "
                     f"{'learned' if self.stages.learned else 'oracle'} stages)")
        tracking = tracking_summary(records)
        writer.value("tracking", tracking)
        fast = timing[(timing["mode"] == "fast") & (timing["maps"] == self.main_maps)]
        if len(fast):
            writer.compare("pose.seconds_from_scratch", "Pose from scratch (init + refine), fast mode",
                           float(fast["initialisation"].iloc[0] + fast["refinement"].iloc[0]), unit="s", paper_key="",
                           note="target ≤ 1 s on 2 cores; the paper ran CUDA and gave no time")
        if tracking:
            writer.compare("pose.seconds_tracking_refine", "Warm-start tracking refinement (median)",
                           tracking["track_refinement_s"], unit="s", digits=3, paper_key="", note="target ≤ 50 ms")
            writer.compare("pose.tracking_error_mm", "Warm-start tracking, focal error", tracking["track_error_mm"],
                           unit="mm", paper_key="")
        return timing.round(3)

    def pose_overlay(self) -> PoseOverlay:
        """Fig. 6's pose: a fresh experiment pose (its own seed) rendered and estimated in
        :attr:`table_mode` with :attr:`main_maps`; the notebook draws it
        (:func:`histostudy.reporting.plot_pose_overlay`) with the returned ``rng``."""
        p = self.parameters
        rng_fig = np.random.default_rng(self.seed_figure)
        scene = random_background(rng_fig, p.background)
        T_true = experiment_pose(rng_fig, self.config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        frames = [render_frame(self.render_model, T_true, v, rng=rng_fig, physical=self.physical, background=scene,
                               **self.config.frame_kwargs()) for v in self.views]
        result = estimate_pose(frames, self.pose_model, segmenter=self.stages.segmenter,
                               orientation=self.stages.orientation, rng=rng_fig, mode=self.table_mode,
                               distance_maps=self.main_maps, raise_on_failure=False)
        focal_error = np.linalg.norm(result.focal_point_mm
                                     - (T_true[:3, :3] @ self.physical.focal_point_mm + T_true[:3, 3]))
        verdict = "" if result.verdict.ok else " — failed verdict: " + "; ".join(result.verdict.reasons)
        caption = (f"Fig. 6 (columns 1-2): X-ray and the digital model in the estimated pose "
                   f"(focal error {focal_error:.2f} mm{verdict})")
        return PoseOverlay(frames, T_true, result.T_carm_transducer, float(focal_error), caption, rng_fig)

    @_written_once
    def write_robustness(self) -> pd.DataFrame:
        """Beyond the paper: initialisation success over random poses (:func:`robustness_sweep`), with
        the oracle stages (both initialisations) and, where the study runs on them, the learned ones
        (and the VGG19 alone as orientation). Returns the success per stages and initialisation."""
        writer, p, stages = self.writer, self.parameters, self.stages
        sweep = dict(**self._models(), seed=int(self.seed_robust.generate_state(1)[0]), config=self.config)
        with writer.timer("robustness sweep"):
            robust = robustness_sweep(p.robustness_poses, **sweep).assign(stages="oracle")
            if stages.learned:
                learned_robust = robustness_sweep(p.robustness_poses, **sweep, inits=("robust",),
                                                  segmenter=stages.segmenter, orientation=stages.orientation)
                robust = pd.concat([robust, learned_robust.assign(stages="learned")], ignore_index=True)
                vgg19 = getattr(stages.orientation, "fallback", None)
                if p.robustness_vgg19 and vgg19 is not None:
                    vgg_robust = robustness_sweep(p.robustness_poses, **sweep, inits=("robust",),
                                                  segmenter=stages.segmenter, orientation=vgg19)
                    robust = pd.concat([robust, vgg_robust.assign(stages="learned-vgg19")], ignore_index=True)
        writer.table("robustness", robust, "Initialisation over random poses: error (mm), verdict, time (s)")
        rates = robustness_summary(robust, by=("stages", "init"))
        writer.table("robustness_summary", rates, "Initialisation over random poses per stages and method: success "
                     "(< 2 mm), refused by the verdict, accepted although off by 2 mm or more", digits=3)
        for comparison in init_success_comparisons(rates):
            writer.compare(**comparison)
        return rates

    @_written_once
    def write_degradation(self) -> pd.DataFrame:
        """Beyond the paper: focal error vs segmentation degradation (:func:`degradation_sweep`)."""
        writer, p = self.writer, self.parameters
        with writer.timer("degradation sweep"):
            degrade = degradation_sweep(p.degradation_levels, **self._models(),
                                        seed=int(self.seed_degrade.generate_state(1)[0]), config=self.config,
                                        n_poses=p.degradation_poses)
        per_level = focal_error_per_level(degrade)
        writer.table("degradation", per_level, "Focal error vs segmentation degradation (fast mode)")
        return per_level

    @_written_once
    def write_learned_stages(self) -> pd.DataFrame | None:
        """The shipped learned stages beside the oracles on the same frames of the first
        ``learned_experiments`` experiments (whichever the study did not run is run here), and the
        focal error vs dose with the learned stages. Returns the comparison (None without them)."""
        writer, p, stages, records = self.writer, self.parameters, self.stages, self._require_records()
        unet, vgg = stages.shipped_segmenter, stages.shipped_orientation
        if unet is None or vgg is None:
            writer.text("The learned stages were not run: " + ("disabled by the profile." if not p.learned_stages else
                        "no usable shipped U-Net and VGG19 in data/models (see notebooks 02 and 03)."))
            return None
        compare_mode = "fast" if "fast" in p.modes else p.modes[0]
        compare_config = replace(self.config, n_experiments=min(p.learned_experiments, p.n_experiments),
                                 modes=(compare_mode,), distance_maps=(self.main_maps,), track=False)
        main_rows = records[(records["mode"] == compare_mode) & (records["maps"] == self.main_maps)
                            & (records["experiment"] < compare_config.n_experiments)]
        other = "oracle" if stages.learned else "learned"
        with writer.timer(f"pose study, {other} stages (comparison)"):
            other_rows = run_pose_study(
                compare_config, **self._models(), seed=self.study_seed,
                segmenter=self.config.segmenter() if stages.learned else unet,
                orientation=OracleOrientation() if stages.learned else vgg)
        learned, oracle = (main_rows, other_rows) if stages.learned else (other_rows, main_rows)
        both = stages_comparison_table(learned, oracle)
        writer.table("learned_vs_oracle", both, "Focal error with the learned stages and with the oracles, same frames")
        writer.value("learned_manifests", {"unet": (unet.manifest or {}).get("weights_file"),
                                           "vgg19": (vgg.manifest or {}).get("weights_file")})
        writer.compare("pose.learned_minus_oracle_mm", "Mean focal error, learned minus oracle stages",
                       float(learned["err_euclidean"].mean() - oracle["err_euclidean"].mean()), unit="mm",
                       paper_key="", note="target ≤ 0.1 mm")
        with writer.timer("noise sweep"):
            noise = noise_sweep(p.noise_photons, **self._models(), seed=int(self.seed_noise.generate_state(1)[0]),
                                config=self.config, segmenter=unet, orientation=vgg, n_poses=p.noise_poses)
        writer.table("noise", focal_error_per_dose(noise), "Focal error vs photons per pixel (learned stages, fast "
                     "mode)")
        return both

    @_written_once
    def write_projector_comparison(self) -> pd.DataFrame | None:
        """Beyond the paper: the same poses from the splatting renderer and RTK's Joseph projector
        (:func:`~histostudy.study.pose.projector_comparison`), where the profile asks and RTK is installed."""
        writer, p, stages = self.writer, self.parameters, self.stages
        if not p.independent_projector:
            writer.text("The independent projector was not run (independent_projector = False in this profile).")
            return None
        if not rtk_available():
            writer.text("The independent projector was not run: itk-rtk is not installed (pip install "
                        "'histostudy[rtk]').")
            return None
        poses = projectors.comparison_poses(self.config, self.study_seed, n_study=p.projector_study_poses,
                                            n_random=p.projector_random_poses, views=self.views,
                                            pose_model=self.pose_model)
        with writer.timer(f"projector comparison, {len(poses)} poses"):
            projected = projectors.projector_comparison(poses, **self._models(), config=self.config,
                                                        seed=self.study_seed, segmenter=stages.segmenter,
                                                        orientation=stages.orientation)
        writer.table("projector_comparison", projected, "Focal error (mm) per pose and projector, verdict, seconds")
        summary = projectors.projector_summary(projected)
        writer.table("projector_summary", summary, "Splatting renderer vs RTK Joseph projector, same poses: "
                     "accepted estimates' focal error (mm), refusals, wrong acceptances, paired difference (mm)",
                     digits=3)
        for row in summary[summary["projector"] == "rtk-joseph"].itertuples():
            writer.compare(f"pose.projector_difference.{row.kind}",
                           f"RTK minus splatting, mean focal error ({row.kind} poses)", row.paired_difference_mm,
                           unit="mm", digits=3, paper_key="", note=f"{stages.why.split(':')[0]}; target within ± 0.1 mm")
        return summary

    @_written_once
    def write_stand_ins(self) -> None:
        """What stands in for the lab's treatment, CBCT, networks and robot, and the closing paragraph."""
        writer, p, records = self.writer, self.parameters, self._require_records()
        if p.cbct_reference:
            writer.stand_in("treatment, post-treatment CBCT and manual segmentation of the treated zone (reference)",
                            "the treatment simulated about the true centre pose (notebook 05's plan, 3x3x6 mm bubble "
                            "clouds at the physical focal point, the layered phantom mixed), a simulated CBCT (0.5 mm "
                            f"blur, 20 HU noise, {p.cbct_voxel_mm} mm voxels) and the automatic zone segmentation; the "
                            "ground truth (true bubble-cloud centre, sphere of radius r) reported beside it")
        else:
            writer.stand_in("post-treatment CBCT, manual segmentation of the treated zone (reference)",
                            "the true bubble-cloud centre (physical focal point in the true pose) and the sphere of "
                            "radius r")
        if not self.stages.learned:
            writer.stand_in("U-Net segmentation (§II-B.2)", "the reference labels degraded to Table I's per-class "
                            "precision and recall (" + self.stages.why + ")")
            writer.stand_in("VGG19 azimuth/elevation (§II-B.4)", "the true angles plus Gaussian errors with the "
                            "paper's MAE")
        writer.stand_in("UR5e moves of 10/12.5 mm along its axes", "exact moves along the transducer's LR/TB/depth "
                        "axes plus 0.01 mm SD positioning noise")
        ok = records["ok"].astype(bool)
        writer.text(f"{len(records)} pose estimates, {int((~ok).sum())} with a failed verdict (listed in "
                    f"`failed_estimates`). Table II is measured against "
                    + ("the post-treatment CBCT (as the paper) and against " if p.cbct_reference else "")
                    + f"the physical transducer's focal point, which differs from the digital model's by "
                    f"{np.linalg.norm(self.physical.focal_point_mm):.2f} mm (manufacturing deviation), the kind of "
                    "bias §IV attributes to model mismatch.")
