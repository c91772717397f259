"""Notebook 04: the paper's pose-estimation experiment (§II-D, §II-E.3, §III, Table II) on synthetic frames.

Each experiment places the transducer with its focal point near the phantom centre, then moves
it by ``r`` (10 or 12.5 mm: a 20 or 25 mm treatment sphere) along the robot's axes to the six
margin points (top/bottom = TB, left/right = LR, front/back = depth). At the centre and each
margin a biplane pair is rendered (the physical transducer, a phantom scene, Poisson noise) and
the pose is estimated. Errors are decomposed along the transducer's depth (the direction of
ultrasound propagation, the transducer's ``-z``), TB (``y``) and LR (``x``) axes, as §II-E.

Two references for the errors (§II-E.3):

- the **ground truth** (:func:`experiment_metrics` without ``reference``): the true bubble-cloud
  centre — the physical transducer's acoustic focal point in the true pose (plus an optional
  offset) — and the sphere of radius ``r`` around it;
- the **post-treatment CBCT**, as the paper (:func:`cbct_reference`, then
  :func:`experiment_metrics` with ``reference=``): the sphere treated at the true focal point,
  the layered phantom mixed there, a CBCT simulated and the zone segmented; its centroid, its
  fitted sphere's surface and its radii along depth/TB/LR are the reference. The difference
  between the two is the error of the reference itself (treatment geometry, CBCT, segmentation).

The robot's axes are taken along the transducer's own LR, TB and depth axes at the centre pose
(the transducer hanging from the UR5e's flange with its axes along the base axes), so that the
radius per direction of Table II is the half distance between opposite margin predictions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from histostudy.geometry import make_transform, matrix_from_euler, rotation_about_axis, rotation_angle
from histostudy.imaging import Anatomy, PhantomSpec, View, phantom_mask, phantom_volume, random_background, render_frame
from histostudy.learning import (OracleOrientation, OracleSegmenter, OrientationSource, SegmentationDegradation,
                                 Segmenter)
from histostudy.pose import MAP_KINDS, PoseEstimationError, estimate_pose, learned_stage_shortfalls
from histostudy.transducer import Feature, TransducerModel, pose_facing
from histostudy.treatment import (STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM, TreatmentZone, plan_treatment,
                                  scan_treated_zone)

__all__ = [
    "DIRECTIONS",
    "StudyStages",
    "study_stages",
    "sweep_visible_points",
    "PoseExperiment",
    "PoseStudyConfig",
    "cbct_reference",
    "experiment_setups",
    "phantom_placement",
    "reference_error_summary",
    "degradation_sweep",
    "margin_positions",
    "robustness_summary",
    "robustness_sweep",
    "run_pose_study",
    "stage_timing",
    "table2",
    "tracking_summary",
    "transducer_axes",
    "variant_summary",
    "axial_symmetric_rotation_error_deg",
    "experiment_metrics",
    "noise_sweep",
    "random_pose_in_views",
]

#: Error directions of §II-E: name -> column of the direction matrix (see :func:`transducer_axes`).
DIRECTIONS = ("depth", "tb", "lr")

#: Margin points: name -> (direction, sign). Paper: top, bottom, left, right, front, back.
MARGINS = {
    "top": ("tb", +1), "bottom": ("tb", -1),
    "left": ("lr", +1), "right": ("lr", -1),
    "front": ("depth", +1), "back": ("depth", -1),
}


@dataclass(frozen=True)
class PoseStudyConfig:
    """Parameters of the pose-estimation study (defaults: the standard profile's).

    Attributes:
        n_experiments: phantom experiments (paper: 10).
        margin_mm: radii drawn per experiment (paper: 10 or 12.5 mm, spheres of 2.0 or 2.5 cm).
        background: scene behind the transducer (paper's pose studies: agarose phantoms).
        photons_per_pixel, n_splats, splat_sigma_mm: rendering (§II-B.2).
        degradation: ``"table1"`` (oracle errs as the paper's U-Net, Table I) or ``"none"``.
        modes: refinement modes to run on the same frames (``"paper"``, ``"fast"``).
        distance_maps: map kinds to run on the same frames (``"occlusion_aware"``, ``"per_class"``,
            see :func:`histostudy.pose.estimate_pose`); every mode runs with every kind.
        track: also re-estimate each margin pose warm-started from the centre's estimate (fast
            mode), as live tracking of a 10-12.5 mm move would.
        tilt_sd_deg: tilt of the transducer axis from vertical (anterior-posterior), per axis.
        focal_jitter_mm: focal point uniform within ± this of the phantom centre, per axis.
        robot_repeatability_mm: SD of the robot's positioning noise (UR5e: ±0.03 mm).
        bubble_offset_mm: offset of the bubble cloud from the acoustic focal point, transducer frame.
    """

    n_experiments: int = 10
    margin_mm: tuple = (10.0, 12.5)
    background: str = "phantom"
    photons_per_pixel: float = 5e4
    n_splats: int = 16
    splat_sigma_mm: float = 0.5
    degradation: str = "table1"
    modes: tuple = ("paper", "fast")
    distance_maps: tuple = ("occlusion_aware",)
    track: bool = True
    tilt_sd_deg: float = 10.0
    focal_jitter_mm: float = 5.0
    robot_repeatability_mm: float = 0.01
    bubble_offset_mm: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.n_experiments < 1:
            raise ValueError(f"n_experiments must be >= 1, got {self.n_experiments!r}")
        if not self.margin_mm or any(not (np.isfinite(r) and r > 0) for r in self.margin_mm):
            raise ValueError(f"margin_mm must hold positive radii in mm, got {self.margin_mm!r}")
        OracleSegmenter.named(self.degradation)  # a clear error now for an unknown name
        if not self.modes or any(m not in ("paper", "fast") for m in self.modes):
            raise ValueError(f"modes must be a non-empty subset of ('paper', 'fast'), got {self.modes!r}")
        if not self.distance_maps or any(m not in MAP_KINDS for m in self.distance_maps):
            raise ValueError(f"distance_maps must be a non-empty subset of {MAP_KINDS}, got {self.distance_maps!r}")

    @property
    def variants(self) -> list[tuple[str, str]]:
        """Every (mode, distance-map kind) pair the study runs on each pair of frames."""
        return [(mode, maps) for mode in self.modes for maps in self.distance_maps]

    def segmenter(self) -> OracleSegmenter:
        """The oracle segmenter of ``degradation``."""
        return OracleSegmenter.named(self.degradation)


@dataclass(frozen=True, eq=False)
class StudyStages:
    """The segmenter and orientation source a pose study runs on, and why those (:func:`study_stages`).

    ``shipped_segmenter`` / ``shipped_orientation`` are the learned networks that were considered
    (None when missing or not asked for), whether or not the study runs on them.
    """

    segmenter: Segmenter
    orientation: OrientationSource
    learned: bool
    why: str
    shipped_segmenter: Segmenter | None = None
    shipped_orientation: OrientationSource | None = None


def study_stages(config, learned: bool = True, *, segmenter=None, orientation=None) -> StudyStages:
    """The stages of a study's pose estimates: learned by default, the oracles where the learned ones
    fall short. ``config``: a :class:`PoseStudyConfig` or any study config with a ``segmenter()``
    giving its oracle (notebook 05's :class:`~histostudy.study.targeting.TargetingStudyConfig`).

    With ``learned``, the shipped U-Net and VGG19 (:func:`histostudy.learning.segment.default_segmenter`,
    :func:`histostudy.pose.conic_orientation.default_orientation`, or the ``segmenter`` / ``orientation``
    given) when their manifests meet :data:`histostudy.pose.LEARNED_STAGE_REQUIREMENTS`;
    otherwise, or without ``learned``, the config's oracles (Table I degradation, the paper's
    angle MAE). ``why`` says which and why, for the report.
    """
    oracles = (config.segmenter(), OracleOrientation())
    if not learned:
        return StudyStages(*oracles, learned=False, why="oracle stages: the learned stages are disabled "
                           "(learned_stages = False)")
    if segmenter is None or orientation is None:
        from histostudy.pose import default_orientation
        from histostudy.learning import default_segmenter

        segmenter = default_segmenter() if segmenter is None else segmenter
        orientation = default_orientation() if orientation is None else orientation
    shipped = dict(shipped_segmenter=segmenter, shipped_orientation=orientation)
    shortfalls = learned_stage_shortfalls(segmenter, orientation)
    if shortfalls:
        return StudyStages(*oracles, learned=False, why="oracle stages (Table I degradation, the paper's angle "
                           "MAE), because " + "; ".join(shortfalls), **shipped)
    names = [(getattr(stage, "manifest", None) or {}).get("weights_file", type(stage).__name__)
             for stage in (segmenter, orientation)]
    if getattr(orientation, "fallback", None) is not None:  # the geometric initialiser
        orientation_text = f"the inner-boundary conic initialiser (VGG19 {names[1]} where it finds no ellipse)"
    else:
        orientation_text = f"the VGG19 {names[1]}"
    return StudyStages(segmenter, orientation, learned=True,
                       why=f"learned stages: the U-Net {names[0]} and {orientation_text}", **shipped)


def transducer_axes(T_carm_transducer) -> dict[str, np.ndarray]:
    """World unit vectors of §II-E's directions for a pose: depth (propagation, ``-z``), TB (``y``), LR (``x``)."""
    R = np.asarray(T_carm_transducer, dtype=np.float64)[:3, :3]
    return {"depth": -R[:, 2], "tb": R[:, 1], "lr": R[:, 0]}


def margin_positions(T_centre, radius_mm: float) -> dict[str, np.ndarray]:
    """The centre pose and the six margin poses: the transducer translated by ``radius_mm`` along
    the robot's axes (here the transducer's own LR/TB/depth axes at the centre pose)."""
    axes = transducer_axes(T_centre)
    out = {"centre": np.array(T_centre, dtype=np.float64)}
    for name, (direction, sign) in MARGINS.items():
        T = out["centre"].copy()
        T[:3, 3] += sign * radius_mm * axes[direction]
        out[name] = T
    return out


def _experiment_pose(rng: np.random.Generator, config: PoseStudyConfig, centre_mm) -> np.ndarray:
    tilt = np.deg2rad(config.tilt_sd_deg)
    direction = (np.tan(rng.normal(0, tilt)), 1.0, np.tan(rng.normal(0, tilt)))
    focal = np.asarray(centre_mm, float) + rng.uniform(-config.focal_jitter_mm, config.focal_jitter_mm, 3)
    return pose_facing(direction, focal, rng.uniform(0, 2 * np.pi))


def _bubble_centre(physical: TransducerModel, T, offset_mm) -> np.ndarray:
    local = np.asarray(physical.focal_point_mm, float) + np.asarray(offset_mm, float)
    return T[:3, :3] @ local + T[:3, 3]


@dataclass(frozen=True, eq=False)
class PoseExperiment:
    """One experiment's set-up as :func:`run_pose_study` draws it (C-arm frame, mm).

    ``radius_mm``: the treatment sphere's radius ``r`` (the robot's move to each margin).
    ``scene``: the phantom set-up behind the transducer. ``T_centre``: the commanded centre pose
    (``T_carm_transducer``); ``T_true``: per position (``"centre"``, then the six margins) the
    reached pose, the robot's repeatability noise included.
    """

    experiment: int
    radius_mm: float
    scene: Anatomy
    T_centre: np.ndarray
    T_true: dict


def _draw_experiments(config: PoseStudyConfig, seed: int):
    """Yield ``(PoseExperiment, rng_render, rng_est, rng_cbct)`` per experiment.

    The one place the experiments are drawn: :func:`run_pose_study` renders and estimates from
    them and :func:`cbct_reference` treats and scans the same set-ups. Streams per experiment:
    children 0-4 of its seed sequence (pose, scene, render, robot, estimation), as ever; child 5
    is the CBCT reference's (treatment positioning noise, CBCT noise), so adding it changes no
    other draw.
    """
    for e, seq in enumerate(np.random.SeedSequence(seed).spawn(config.n_experiments)):
        rng_pose, rng_scene, rng_render, rng_robot, rng_est, rng_cbct = (np.random.default_rng(s) for s in seq.spawn(6))
        radius = float(rng_pose.choice(config.margin_mm))
        scene = random_background(rng_scene, config.background)
        centre = scene.meta.get("phantom_center_mm", np.zeros(3))
        T_centre = _experiment_pose(rng_pose, config, centre)
        T_true = {}
        for position, T_nominal in margin_positions(T_centre, radius).items():
            T = T_nominal.copy()
            T[:3, 3] += rng_robot.normal(0, config.robot_repeatability_mm, 3)
            T_true[position] = T
        yield PoseExperiment(e, radius, scene, T_centre, T_true), rng_render, rng_est, rng_cbct


def experiment_setups(config: PoseStudyConfig, seed: int) -> list[PoseExperiment]:
    """The experiments :func:`run_pose_study` runs for ``config`` and ``seed`` (no rendering)."""
    return [exp for exp, *_ in _draw_experiments(config, seed)]


def run_pose_study(config: PoseStudyConfig, *, pose_model: TransducerModel, render_model: TransducerModel,
                   physical: TransducerModel, views: Sequence[View], seed: int,
                   segmenter: Segmenter | None = None, orientation: OrientationSource | None = None,
                   progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Run the experiments; one row per (experiment, position, mode, maps), plus tracking rows.

    Columns: experiment, radius_mm, position, mode, maps, the true and predicted focal points
    (``true_*``, ``pred_*``, world mm), the error along depth/TB/LR of the experiment's centre
    pose (``err_depth`` ...), ``err_euclidean``, ``rotation_error_deg`` (modulo the transducer's
    half-turn symmetry), cost, iterations, seconds per stage (``s_*``), ``ok`` and the failure
    text (a failed estimate keeps NaN predictions). With ``config.track``, rows of mode
    ``"track"`` hold the margin poses re-estimated from the centre's estimate (warm start).

    ``segmenter`` and ``orientation`` default to the config's oracles (Table I degradation and
    the paper's angle MAE); pass learned ones to run the study on them.
    """
    rows = []
    segmenter = config.segmenter() if segmenter is None else segmenter
    orientation = OracleOrientation() if orientation is None else orientation
    for exp, rng_render, rng_est, _ in _draw_experiments(config, seed):
        e, radius, scene = exp.experiment, exp.radius_mm, exp.scene
        axes = transducer_axes(exp.T_centre)
        centre_estimate = None
        for position, T_true in exp.T_true.items():
            frames = [render_frame(render_model, T_true, v, rng=rng_render, physical=physical, background=scene,
                                   photons_per_pixel=config.photons_per_pixel, n_splats=config.n_splats,
                                   splat_sigma_mm=config.splat_sigma_mm) for v in views]
            truth = _bubble_centre(physical, T_true, config.bubble_offset_mm)
            variants = list(config.variants)
            if config.track and position != "centre":
                variants.append(("track", config.distance_maps[0]))
            for mode, maps in variants:
                rng_mode = np.random.default_rng(rng_est.integers(2**63))
                row = {"experiment": e, "radius_mm": radius, "position": position, "mode": mode, "maps": maps,
                       **{f"true_{a}": v for a, v in zip("xyz", truth)}}
                kwargs = dict(mode=mode, distance_maps=maps)
                if mode == "track":
                    if centre_estimate is None:
                        continue
                    kwargs.update(mode="fast", initial_pose=centre_estimate)
                try:
                    res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                        rng=rng_mode, **kwargs)
                    if position == "centre" and (mode, maps) == config.variants[0]:
                        centre_estimate = res.T_carm_transducer
                    pred = res.focal_point_mm + res.T_carm_transducer[:3, :3] @ np.asarray(config.bubble_offset_mm)
                    err = pred - truth
                    row.update({f"pred_{a}": v for a, v in zip("xyz", pred)})
                    row.update({f"err_{d}": float(err @ axes[d]) for d in DIRECTIONS})
                    row.update(err_euclidean=float(np.linalg.norm(err)),
                               rotation_error_deg=axial_symmetric_rotation_error_deg(res.T_carm_transducer, T_true),
                               cost=res.cost, iterations=res.iterations, ok=True, failure="",
                               **{f"s_{k}": v for k, v in res.timings_s.items()})
                except PoseEstimationError as exc:
                    row.update({f"pred_{a}": np.nan for a in "xyz"}, **{f"err_{d}": np.nan for d in DIRECTIONS},
                               err_euclidean=np.nan, ok=False, failure=str(exc))
                rows.append(row)
            if progress:
                progress(f"experiment {e + 1}/{config.n_experiments}: {position}")
    return pd.DataFrame(rows)


def axial_symmetric_rotation_error_deg(T_estimate, T_true) -> float:
    """Rotation error (deg) between two poses, up to a half turn about the transducer axis.

    The aperture, quadrant gaps and cutout are symmetric under a half turn about the axis, and
    §II-B.4's axial search covers [0, 180 deg) only: a half-turn flip moves no focal point.
    """
    R_est = np.asarray(T_estimate, dtype=np.float64)[:3, :3]
    R_true = np.asarray(T_true, dtype=np.float64)[:3, :3]
    flip = np.diag([-1.0, -1.0, 1.0])  # half turn about the transducer's z axis
    return float(min(np.rad2deg(rotation_angle(R_est.T @ R_true)),
                     np.rad2deg(rotation_angle((R_est @ flip).T @ R_true))))


# ---------------------------------------------------------------------------------------------
# The post-treatment CBCT reference (§II-D, §II-E.3)
# ---------------------------------------------------------------------------------------------

#: Columns :func:`experiment_metrics` reads from a reference table (:func:`cbct_reference`).
REFERENCE_COLUMNS = ("experiment", "centroid_x", "centroid_y", "centroid_z", "sphere_x", "sphere_y", "sphere_z",
                     "sphere_radius_mm", *(f"ref_radius_{d}" for d in DIRECTIONS),
                     *(f"axis_{d}_{a}" for d in DIRECTIONS for a in "xyz"))


def phantom_placement(scene: Anatomy, centre_mm=(0.0, 0.0, 0.0)) -> tuple[PhantomSpec, np.ndarray]:
    """The layered phantom of a scene as :mod:`histostudy.imaging.cbct` models it (§II-D.1):
    ``(PhantomSpec, T_carm_phantom)``.

    A phantom scene (:func:`histostudy.imaging.anatomy.random_phantom_setup`) records its cube's edge,
    centre, yaw about the vertical axis and layer thickness; its layers are stacked vertically as
    poured, so the phantom frame's +z (the stacking axis of :class:`PhantomSpec`) is world ``-y``
    (up). The layers' phase is :class:`PhantomSpec`'s (from the bottom face), not the scene's: the
    fluoroscopy never sees it and the CBCT reference does not depend on it. A scene without a
    phantom (abdomen) gets the default 5 cm phantom at ``centre_mm`` (world mm), layers horizontal.
    """
    if not isinstance(scene, Anatomy):
        raise TypeError(f"scene must be a histostudy.imaging.anatomy.Anatomy, got {type(scene).__name__}")
    meta = scene.meta
    up = rotation_about_axis([1.0, 0.0, 0.0], np.pi / 2)  # phantom z -> world -y
    if "phantom_center_mm" not in meta:
        return PhantomSpec(), make_transform(up, np.asarray(centre_mm, dtype=np.float64))
    spec = PhantomSpec(size_mm=float(meta.get("phantom_edge_mm", PhantomSpec.size_mm)),
                       layer_thickness_mm=float(meta.get("layer_mm", PhantomSpec.layer_thickness_mm)))
    yaw = rotation_about_axis([0.0, 1.0, 0.0], np.deg2rad(float(meta.get("phantom_yaw_deg", 0.0))))
    return spec, make_transform(yaw @ up, np.asarray(meta["phantom_center_mm"], dtype=np.float64))


def _positive(value, name: str, allow_zero: bool = False):
    arr = np.asarray(value, dtype=np.float64)
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0) or (not allow_zero and np.any(arr == 0)):
        raise ValueError(f"{name} must be finite and {'>= 0' if allow_zero else '> 0'} (mm or HU), got {value!r}")
    return value


def _treat_and_scan(exp: PoseExperiment, spec: PhantomSpec, T_carm_phantom: np.ndarray, *, physical: TransducerModel,
                    config: PoseStudyConfig, rng: np.random.Generator, phantom_voxel_mm, cbct_voxel_mm,
                    cbct_blur_mm: float, cbct_noise_hu: float, treatment_spacing_mm, treatment_inset_mm):
    """The paper's treatment of one pose experiment and its post-treatment CBCT, segmented.

    The sphere of radius ``r`` is planned about the centre pose's TCP (the geometric focal point)
    on the centre pose's axes; the robot translates the transducer through the plan without
    turning it (its repeatability noise added); the bubble clouds sit at the physical
    transducer's focal point plus ``config.bubble_offset_mm`` for each reached pose.
    """
    T_c = exp.T_true["centre"]
    R = T_c[:3, :3]
    plan = plan_treatment(TreatmentZone(T_c[:3, 3], 2.0 * exp.radius_mm), treatment_spacing_mm, axes=R,
                          inset_mm=treatment_inset_mm)
    reached = np.repeat(T_c[None], len(plan), axis=0)
    reached[:, :3, 3] = plan.points_mm + rng.normal(0.0, config.robot_repeatability_mm, plan.points_mm.shape)
    phantom = phantom_volume(spec, T_carm_phantom, spacing_mm=phantom_voxel_mm)
    roi = phantom_mask(phantom, spec, T_carm_phantom)
    seg, post = scan_treated_zone(phantom, roi, reached, physical.focal_point_mm, config.bubble_offset_mm, spec=spec,
                                  T_carm_phantom=T_carm_phantom, rng=rng, blur_sigma_mm=cbct_blur_mm,
                                  noise_sd_hu=cbct_noise_hu, voxel_mm=cbct_voxel_mm)
    return seg, post, len(plan)


def cbct_reference(config: PoseStudyConfig, *, physical: TransducerModel, seed: int,
                   records: pd.DataFrame | None = None, phantom_voxel_mm=0.5, cbct_voxel_mm=1.0,
                   cbct_blur_mm: float = 0.5, cbct_noise_hu: float = 20.0,
                   treatment_spacing_mm=STUDY_PLAN_SPACING_MM, treatment_inset_mm=STUDY_PLAN_INSET_MM,
                   keep_volumes: bool = False, progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """The paper's reference of Table II (§II-D, §II-E.3): the treated zone in a post-treatment CBCT.

    For each experiment of :func:`run_pose_study` with the same ``config`` and ``seed`` (the
    set-ups are redrawn by :func:`experiment_setups`; no rendering), as the paper did after the
    fluoroscopy: a sphere of radius ``r`` treated about the true centre pose (the transducer
    translated through :func:`histostudy.treatment.plan_treatment`'s focal points on the centre
    pose's axes; bubble clouds at the physical focal point plus ``config.bubble_offset_mm``), the
    layered phantom of the experiment's scene (:func:`phantom_placement`) mixed there, a
    post-treatment CBCT simulated (:func:`histostudy.imaging.cbct.simulate_cbct`: ``cbct_blur_mm``,
    ``cbct_noise_hu``, voxels of ``cbct_voxel_mm``; the true phantom on ``phantom_voxel_mm``) and
    the zone segmented (:func:`histostudy.treatment.zone.segment_treatment_zone`, the automatic stand-in for
    the paper's manual annotation). Defaults: notebook 05's (0.5 mm phantom, 1 mm CBCT, 0.5 mm
    blur, 20 HU noise, the studies' plan: spacing (2, 2, 3) mm, inset (1.25, 1.25, 2.25) mm).

    ``records``: :func:`run_pose_study`'s rows; when given, only its experiments are treated and
    each one's true centre is checked against the redrawn set-up (a different config or seed is
    refused). One row per experiment, C-arm frame, mm:

    - ``experiment``, ``radius_mm`` (``r``), ``true_x/y/z``: the true bubble-cloud centre at the
      centre pose (the ground-truth reference);
    - ``centroid_x/y/z``: the segmented zone's centroid (the reference centre, §II-E.3);
      ``sphere_x/y/z``, ``sphere_radius_mm``: its least-squares sphere (the surface the margin
      points are measured to);
    - ``ref_radius_depth/tb/lr``: the zone's radius along the centre pose's depth/TB/LR axes
      (through the centroid, :meth:`~histostudy.treatment.zone.ZoneSegmentation.radii_along`), and those
      axes as world unit vectors ``axis_<d>_x/y/z``;
    - the error of the reference against the ground truth: ``ref_err_<d>`` and
      ``ref_err_euclidean`` (centroid minus true centre), ``ref_radius_err_<d>`` and
      ``sphere_radius_err_mm`` (minus ``r``);
    - ``clearance_mm``: least distance of the nominal sphere to the phantom's faces (the
      segmentation keeps to half a window, 4 mm, inside them: below that the zone is clipped);
      ``n_points`` (plan), ``volume_mm3``, ``seconds``; ``ok`` and ``failure``: a segmentation
      that finds no zone leaves the experiment without a reference (NaN, skipped by Table II's
      means) instead of stopping the study; with ``keep_volumes``, ``_volumes`` (the
      post-treatment CBCT and the segmentation).

    Pass the table to :func:`experiment_metrics` (``reference=``) for Table II against it.
    """
    if not isinstance(physical, TransducerModel):
        raise TypeError(f"physical must be a histostudy.transducer.TransducerModel, got {type(physical).__name__}")
    _positive(phantom_voxel_mm, "phantom_voxel_mm")
    _positive(cbct_voxel_mm, "cbct_voxel_mm")
    _positive(cbct_blur_mm, "cbct_blur_mm", allow_zero=True)
    _positive(cbct_noise_hu, "cbct_noise_hu", allow_zero=True)
    wanted = None
    if records is not None:
        need = {"experiment", "position", "radius_mm", "true_x", "true_y", "true_z"}
        if not isinstance(records, pd.DataFrame) or not need <= set(records.columns):
            raise ValueError(f"records must be run_pose_study's rows with columns {sorted(need)}")
        centres = records[records["position"] == "centre"].groupby("experiment").first()
        wanted = set(int(e) for e in records["experiment"].unique())
        beyond = sorted(e for e in wanted if not 0 <= e < config.n_experiments)
        if beyond:
            raise ValueError(f"records hold experiments {beyond} beyond config.n_experiments={config.n_experiments}: "
                             "pass the config and seed the records were made with")
    rows = []
    for exp, _, _, rng_cbct in _draw_experiments(config, seed):
        if wanted is not None and exp.experiment not in wanted:
            continue
        truth = _bubble_centre(physical, exp.T_true["centre"], config.bubble_offset_mm)
        if wanted is not None:
            got = centres.loc[exp.experiment, ["true_x", "true_y", "true_z"]].to_numpy(float) \
                if exp.experiment in centres.index else None
            if got is None or not np.allclose(got, truth, atol=1e-6) \
                    or float(centres.loc[exp.experiment, "radius_mm"]) != exp.radius_mm:
                raise ValueError(f"experiment {exp.experiment}: the records' true centre {got} and radius do not "
                                 f"match the set-up redrawn from this config and seed (true centre "
                                 f"{truth.round(3).tolist()}, r = {exp.radius_mm} mm): pass the config, seed and "
                                 "physical transducer the records were made with")
        t0 = time.perf_counter()
        spec, T_cp = phantom_placement(exp.scene)
        axes = transducer_axes(exp.T_true["centre"])
        R = exp.T_true["centre"][:3, :3]
        local = np.linalg.solve(T_cp[:3, :3], truth - T_cp[:3, 3])
        clearance = float(0.5 * spec.size_mm - np.abs(local).max() - exp.radius_mm)
        try:
            seg, post, n_points = _treat_and_scan(exp, spec, T_cp, physical=physical, config=config, rng=rng_cbct,
                                                  phantom_voxel_mm=phantom_voxel_mm, cbct_voxel_mm=cbct_voxel_mm,
                                                  cbct_blur_mm=cbct_blur_mm, cbct_noise_hu=cbct_noise_hu,
                                                  treatment_spacing_mm=treatment_spacing_mm,
                                                  treatment_inset_mm=treatment_inset_mm)
        except ValueError as exc:  # nothing segmented: the experiment has no reference (NaN), as a lost CBCT
            nan = float("nan")
            rows.append({"experiment": exp.experiment, "radius_mm": exp.radius_mm,
                         **{f"true_{a}": v for a, v in zip("xyz", truth)},
                         **{c: nan for c in REFERENCE_COLUMNS[1:]},
                         **{f"ref_err_{d}": nan for d in (*DIRECTIONS, "euclidean")},
                         **{f"ref_radius_err_{d}": nan for d in DIRECTIONS}, "sphere_radius_err_mm": nan,
                         "clearance_mm": clearance, "n_points": 0, "volume_mm3": nan,
                         "ok": False, "failure": str(exc), "seconds": time.perf_counter() - t0})
            continue
        radii = dict(zip(("lr", "tb", "depth"), seg.radii_along(R)))  # columns of R: LR, TB, -depth
        err = seg.centroid_mm - truth
        row = {"experiment": exp.experiment, "radius_mm": exp.radius_mm,
               **{f"true_{a}": v for a, v in zip("xyz", truth)},
               **{f"centroid_{a}": v for a, v in zip("xyz", seg.centroid_mm)},
               **{f"sphere_{a}": v for a, v in zip("xyz", seg.sphere_centre_mm)},
               "sphere_radius_mm": seg.sphere_radius_mm,
               **{f"ref_radius_{d}": float(radii[d]) for d in DIRECTIONS},
               **{f"axis_{d}_{a}": float(v) for d in DIRECTIONS for a, v in zip("xyz", axes[d])},
               **{f"ref_err_{d}": float(err @ axes[d]) for d in DIRECTIONS},
               "ref_err_euclidean": float(np.linalg.norm(err)),
               **{f"ref_radius_err_{d}": float(radii[d] - exp.radius_mm) for d in DIRECTIONS},
               "sphere_radius_err_mm": float(seg.sphere_radius_mm - exp.radius_mm),
               "clearance_mm": clearance, "n_points": n_points, "volume_mm3": seg.volume_mm3,
               "ok": True, "failure": "", "seconds": time.perf_counter() - t0}
        if keep_volumes:
            row["_volumes"] = {"post": post, "segmentation": seg, "T_carm_phantom": T_cp}
        rows.append(row)
        if progress:
            progress(f"CBCT reference {exp.experiment + 1}/{config.n_experiments}: centroid "
                     f"{row['ref_err_euclidean']:.2f} mm from the true centre")
    return pd.DataFrame(rows)


def reference_error_summary(reference: pd.DataFrame) -> pd.DataFrame:
    """The error of the CBCT reference against the ground truth (mean ± SD over experiments, mm):
    centroid minus true bubble-cloud centre along depth/TB/LR and Euclidean, zone radius along
    each direction and fitted sphere radius minus ``r`` (signed: negative = the zone reads small)."""
    _check_reference(reference)
    fmt = lambda v: f"{v[0]:+.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
    rows = [{"quantity": f"centroid − true centre, {d}", "mm": fmt(_mean_sd(reference[f"ref_err_{d}"]))}
            for d in DIRECTIONS]
    rows.append({"quantity": "centroid − true centre, Euclidean",
                 "mm": fmt(_mean_sd(reference["ref_err_euclidean"]))})
    rows += [{"quantity": f"zone radius − r, {d}", "mm": fmt(_mean_sd(reference[f"ref_radius_err_{d}"]))}
             for d in DIRECTIONS]
    rows.append({"quantity": "fitted sphere radius − r", "mm": fmt(_mean_sd(reference["sphere_radius_err_mm"]))})
    return pd.DataFrame(rows)


def _check_reference(reference) -> dict:
    """``{experiment: row}`` of a reference table, after checking its columns."""
    if not isinstance(reference, pd.DataFrame):
        raise TypeError(f"reference must be cbct_reference()'s DataFrame (or None for the ground truth), "
                        f"got {type(reference).__name__}")
    missing = [c for c in REFERENCE_COLUMNS if c not in reference.columns]
    if missing:
        raise ValueError(f"reference lacks the columns {missing}: pass the table cbct_reference() returns")
    if reference["experiment"].duplicated().any():
        raise ValueError("reference holds an experiment twice: one row per experiment expected")
    return {int(r["experiment"]): r for _, r in reference.iterrows()}


def _mean_sd(values) -> tuple[float, float]:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0


def experiment_metrics(records: pd.DataFrame, reference: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per experiment and mode, the quantities of Table II (mm, §II-E.3), from :func:`run_pose_study`'s rows.

    Centre error per direction (signed, predicted minus reference, along the centre pose's
    depth/TB/LR axes) and Euclidean; margin error per margin (distance of the predicted margin
    point to the reference surface); predicted radius per direction (half the distance between
    opposite margin predictions) and its absolute error against the reference radius in that
    direction; precision (distance between the centroid of the six margin predictions and the
    centre prediction; needs no reference).

    ``reference``:

    - ``None`` (the ground truth): the true bubble-cloud centre of the records, the sphere of
      radius ``r`` about it, radius ``r`` in every direction;
    - :func:`cbct_reference`'s table (the paper's reference): the segmented zone's centroid, the
      surface of its fitted sphere, its radii along depth/TB/LR. Every experiment of the records
      needs a row.

    Column ``reference`` says which (``"truth"`` or ``"cbct"``).
    """
    refs = None if reference is None else _check_reference(reference)
    out = []
    full = records[records["mode"] != "track"]
    for (e, mode, maps), g in full.groupby(["experiment", "mode", "maps"], sort=True):
        g = g.set_index("position")
        r = float(g["radius_mm"].iloc[0])
        pred = {p: g.loc[p, ["pred_x", "pred_y", "pred_z"]].to_numpy(float) for p in g.index}
        row = {"experiment": e, "mode": mode, "maps": maps, "radius_mm": r,
               "reference": "truth" if refs is None else "cbct"}
        if refs is None:
            for d in DIRECTIONS:
                row[f"centre_err_{d}"] = float(g.loc["centre", f"err_{d}"])
            row["centre_err_euclidean"] = float(g.loc["centre", "err_euclidean"])
            # Reference sphere: centred on the true centre, radius r (the robot moves exactly r).
            surface_centre = g.loc["centre", ["true_x", "true_y", "true_z"]].to_numpy(float)
            surface_radius = r
            ref_radius = {d: r for d in DIRECTIONS}
        else:
            if int(e) not in refs:
                raise ValueError(f"reference has no row for experiment {e}: run cbct_reference with the records' "
                                 f"config and seed (it has experiments {sorted(refs)})")
            ref = refs[int(e)]
            centroid = ref[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float)
            err = pred["centre"] - centroid
            for d in DIRECTIONS:
                axis = ref[[f"axis_{d}_{a}" for a in "xyz"]].to_numpy(float)
                row[f"centre_err_{d}"] = float(err @ axis)
            row["centre_err_euclidean"] = float(np.linalg.norm(err))
            surface_centre = ref[["sphere_x", "sphere_y", "sphere_z"]].to_numpy(float)
            surface_radius = float(ref["sphere_radius_mm"])
            ref_radius = {d: float(ref[f"ref_radius_{d}"]) for d in DIRECTIONS}
        for name in MARGINS:
            row[f"margin_err_{name}"] = abs(float(np.linalg.norm(pred[name] - surface_centre)) - surface_radius)
        for d in DIRECTIONS:
            plus, minus = [n for n, (dd, s) in MARGINS.items() if dd == d and s > 0][0], \
                [n for n, (dd, s) in MARGINS.items() if dd == d and s < 0][0]
            row[f"radius_{d}"] = 0.5 * float(np.linalg.norm(pred[plus] - pred[minus]))
            row[f"radius_err_{d}"] = abs(row[f"radius_{d}"] - ref_radius[d])
            row[f"margin_err_{d}"] = 0.5 * (row[f"margin_err_{plus}"] + row[f"margin_err_{minus}"])
        margins = np.array([pred[n] for n in MARGINS])
        row["margin_err_overall"] = float(np.mean([row[f"margin_err_{n}"] for n in MARGINS]))
        row["radius_err_overall"] = float(np.mean([row[f"radius_err_{d}"] for d in DIRECTIONS]))
        row["precision"] = float(np.linalg.norm(margins.mean(axis=0) - pred["centre"]))
        out.append(row)
    return pd.DataFrame(out)


def table2(metrics: pd.DataFrame, mode: str, maps: str = "occlusion_aware") -> tuple[pd.DataFrame, dict]:
    """Table II (§III; mean ± SD over experiments, mm) for one mode and map kind, and the values
    keyed as in :mod:`histostudy.reporting.paper` (``table2.<row>.<direction>`` -> (mean, sd)), plus
    ``pose.precision`` (centroid of the six margin predictions vs the centre prediction).

    The reference is the one :func:`experiment_metrics` measured against (its ``reference``
    column: the ground truth, or the post-treatment CBCT of :func:`cbct_reference` as the paper);
    metrics against both mixed are refused.
    """
    m = metrics[(metrics["mode"] == mode) & (metrics["maps"] == maps)]
    if m.empty:
        raise ValueError(f"no experiment metrics for mode={mode!r}, maps={maps!r}; have "
                         f"{sorted(set(zip(metrics['mode'], metrics['maps'])))}")
    if "reference" in m and m["reference"].nunique() > 1:
        raise ValueError(f"metrics mix references {sorted(m['reference'].unique())}: compute Table II per reference")
    values = {}
    for d in DIRECTIONS:
        values[f"table2.center_bias.{d}"] = _mean_sd(m[f"centre_err_{d}"])
        values[f"table2.center_mae.{d}"] = _mean_sd(np.abs(m[f"centre_err_{d}"]))
        values[f"table2.margin_mae.{d}"] = _mean_sd(m[f"margin_err_{d}"])
        values[f"table2.radius_mae.{d}"] = _mean_sd(m[f"radius_err_{d}"])
    values["table2.center_mae.overall"] = _mean_sd(m["centre_err_euclidean"])
    values["table2.margin_mae.overall"] = _mean_sd(m[[f"margin_err_{n}" for n in MARGINS]].to_numpy().ravel())
    values["table2.radius_mae.overall"] = _mean_sd(m[[f"radius_err_{d}" for d in DIRECTIONS]].to_numpy().ravel())
    values["pose.precision"] = _mean_sd(m["precision"])
    fmt = lambda v: f"{v[0]:.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
    rows = []
    for row, label in (("center_bias", "Center Bias"), ("center_mae", "Center MAE"),
                       ("margin_mae", "Margin MAE"), ("radius_mae", "Radius MAE")):
        cells = {"": label}
        for d, col in zip(("depth", "tb", "lr", "overall"), ("Depth", "TB", "LR", "Overall")):
            key = f"table2.{row}.{d}"
            cells[col] = fmt(values[key]) if key in values else "N/A"
        rows.append(cells)
    return pd.DataFrame(rows), values


def variant_summary(metrics: pd.DataFrame) -> pd.DataFrame:
    """Per (mode, maps): centre Euclidean error, centre MAE per direction, radius MAE and precision
    (mean ± SD over experiments, mm) — the paper's mode beside the fast one, per-class maps beside
    occlusion-aware ones."""
    rows = []
    for (mode, maps), m in metrics.groupby(["mode", "maps"], sort=False):
        row = {"mode": mode, "maps": maps, "experiments": len(m)}
        for label, values in (("centre euclidean", m["centre_err_euclidean"]),
                              *((f"centre |{d}|", np.abs(m[f"centre_err_{d}"])) for d in DIRECTIONS),
                              ("radius MAE", m[[f"radius_err_{d}" for d in DIRECTIONS]].to_numpy().ravel()),
                              ("precision", m["precision"])):
            mean, sd = _mean_sd(values)
            row[label] = f"{mean:.2f} ± {sd:.2f}" if np.isfinite(mean) else "n/a"
        rows.append(row)
    return pd.DataFrame(rows)


def stage_timing(records: pd.DataFrame) -> pd.DataFrame:
    """Median seconds per stage of :func:`histostudy.pose.estimate_pose`, per (mode, maps).

    Mode ``"track"`` is the warm start from the previous estimate (no initialisation).
    """
    stages = [c for c in records.columns if c.startswith("s_")]
    ok = records[records["ok"].astype(bool)]
    table = ok.groupby(["mode", "maps"], sort=False)[stages].median()
    table.columns = [c[2:] for c in stages]
    table.insert(0, "estimates", ok.groupby(["mode", "maps"], sort=False).size())
    return table.reset_index()


def tracking_summary(records: pd.DataFrame) -> dict:
    """Warm-started margin estimates (mode ``"track"``) beside the same margins estimated from
    scratch in the fast mode: focal error (mean ± SD, mm) and refinement time (median, s)."""
    track = records[records["mode"] == "track"]
    if track.empty:
        return {}
    scratch = records[(records["mode"] == "fast") & (records["position"] != "centre")
                      & (records["maps"] == track["maps"].iloc[0])]
    out = {"n": int(len(track)), "failed": int((~track["ok"].astype(bool)).sum())}
    for name, df in (("track", track), ("scratch", scratch)):
        mean, sd = _mean_sd(df["err_euclidean"])
        out[f"{name}_error_mm"] = (mean, sd)
        out[f"{name}_refinement_s"] = float(np.nanmedian(df["s_refinement"])) if len(df) else float("nan")
        out[f"{name}_total_s"] = float(np.nanmedian(df["s_total"])) if len(df) else float("nan")
    return out


def random_pose_in_views(rng: np.random.Generator, views: Sequence[View], *, translation_mm: float = 100.0,
                         visible_points_mm=((0.0, 0.0, 0.0),), max_tries: int = 1000) -> np.ndarray:
    """A pose in the paper's training ranges (§II-B.2: Euler angles in [0, 360) deg, translations
    in ±10 cm per axis) whose ``visible_points_mm`` (transducer frame; default the focal point)
    all project onto every detector, in front of the source (rejection sampling)."""
    local = np.asarray(visible_points_mm, dtype=np.float64).reshape(-1, 3)
    for _ in range(max_tries):
        R = matrix_from_euler(rng.uniform(0, 2 * np.pi, 3), "xyz")
        t = rng.uniform(-translation_mm, translation_mm, 3)
        world = local @ R.T + t
        if all(np.all(v.in_image(v.project(world))) and np.all(v.project_homogeneous(world)[:, 2] > 0)
               for v in views):
            return make_transform(R, t)
    raise RuntimeError(f"no pose with {len(local)} given point(s) in every view after {max_tries} draws")


def sweep_visible_points(pose_model: TransducerModel) -> np.ndarray:
    """``(2, 3)`` transducer-frame points a random pose of the sweeps must show in every view: the
    focal point and the transducer's centre (the centroid of the model's element points)."""
    centre = np.mean(pose_model.points[Feature.TRANSDUCER], axis=0)
    return np.stack([np.asarray(pose_model.focal_point_mm, float), centre])


def robustness_sweep(n_poses: int, *, pose_model: TransducerModel, render_model: TransducerModel,
                     physical: TransducerModel, views: Sequence[View], seed: int, config: PoseStudyConfig,
                     inits: Sequence[str] = ("robust", "paper"), mode: str = "fast",
                     success_mm: float = 2.0, segmenter: Segmenter | None = None,
                     orientation: OrientationSource | None = None, workers: int = 1) -> pd.DataFrame:
    """Initialisation success over random poses in the paper's training ranges; one row per (pose, init).

    The focal point and the transducer's centre (the centroid of the model's element points)
    project into every view: the transducer is seen, at least half of it, as in every use of
    the system. Success: no :class:`PoseEstimationError` and a focal-point error below ``success_mm``.
    Backgrounds are drawn from the paper's evaluation mix (abdomen and phantom). ``segmenter``
    and ``orientation`` default to the config's oracles (Table I degradation, the paper's angle
    MAE); pass the learned ones to measure the whole pipeline.

    ``workers`` > 1 spreads the poses over that many spawned processes (one torch thread each).
    Every pose draws from its own child of ``SeedSequence(seed)``, so the rows are the same as
    with one worker. Each row also records the verdict's reasons (``failure``) and, per view, its
    statistics (``rms_<view>``, ``body_rms_<view>``, ``unexplained_<view>``,
    ``disagreement_mm_<view>``; NaN where not reached).
    """
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    segmenter = config.segmenter() if segmenter is None else segmenter
    orientation = OracleOrientation() if orientation is None else orientation
    shared = dict(pose_model=pose_model, render_model=render_model, physical=physical, views=list(views),
                  config=config, inits=tuple(inits), mode=mode, success_mm=success_mm, segmenter=segmenter,
                  orientation=orientation)
    poses = list(enumerate(np.random.SeedSequence(seed).spawn(n_poses)))
    if workers == 1 or n_poses < 2:
        per_pose = [_sweep_pose(i, seq, **shared) for i, seq in poses]
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawned, not forked: a fork of a process whose torch/OpenMP pools are running can hang
        with ProcessPoolExecutor(max_workers=int(workers), mp_context=multiprocessing.get_context("spawn"),
                                 initializer=_init_sweep_worker, initargs=(shared,)) as pool:
            per_pose = list(pool.map(_sweep_pose_in_worker, poses))
    return pd.DataFrame([row for rows in per_pose for row in rows])


_SWEEP_SHARED: dict = {}


def _init_sweep_worker(shared: dict) -> None:
    try:
        import torch
        torch.set_num_threads(1)
    except ImportError:
        pass
    _SWEEP_SHARED.update(shared)


def _sweep_pose_in_worker(pose) -> list[dict]:
    return _sweep_pose(*pose, **_SWEEP_SHARED)


def _sweep_pose(i: int, seq: np.random.SeedSequence, *, pose_model, render_model, physical, views, config, inits,
                mode, success_mm, segmenter, orientation) -> list[dict]:
    rng_pose, rng_scene, rng_render, rng_est = (np.random.default_rng(s) for s in seq.spawn(4))
    T = random_pose_in_views(rng_pose, views, visible_points_mm=sweep_visible_points(pose_model))
    scene = random_background(rng_scene, "mixed")
    frames = [render_frame(render_model, T, v, rng=rng_render, physical=physical, background=scene,
                           photons_per_pixel=config.photons_per_pixel, n_splats=config.n_splats,
                           splat_sigma_mm=config.splat_sigma_mm) for v in views]
    truth = _bubble_centre(physical, T, config.bubble_offset_mm)
    rows = []
    for init in inits:
        row = {"pose": i, "init": init, "scene": scene.kind}
        t0 = time.perf_counter()
        try:
            res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                rng=np.random.default_rng(rng_est.integers(2**63)), mode=mode, init=init,
                                raise_on_failure=False)
        except PoseEstimationError as exc:  # nothing segmented in a view: no pose at all
            row.update(error_mm=np.nan, verdict_ok=False, success=False, failure=str(exc)[:120])
        else:
            err = float(np.linalg.norm(res.focal_point_mm - truth))
            v = res.verdict
            row.update(error_mm=err, verdict_ok=v.ok, success=v.ok and err < success_mm,
                       failure="" if v.ok else ("implausible pose: " + "; ".join(v.reasons))[:200])
            for view in views:
                name = view.name
                row[f"rms_{name}"] = v.rms_distance_px.get(name, np.nan)
                row[f"body_rms_{name}"] = v.class_rms_distance_px.get(name, {}).get(Feature.TRANSDUCER.name.lower(), np.nan)
                row[f"unexplained_{name}"] = v.unexplained_fraction.get(name, np.nan)
                row[f"disagreement_mm_{name}"] = v.view_disagreement_mm.get(name, np.nan)
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
    return rows


def robustness_summary(robust: pd.DataFrame, by: Sequence[str] = ("init",)) -> pd.DataFrame:
    """Per group of :func:`robustness_sweep` rows: poses, success rate, how many the verdict refused,
    how many it accepted although the focal point is off by ``success_mm`` or more (the dangerous
    outcome: a robot would be sent there), median error (mm) and median time (s)."""
    missing = {"pose", "success", "verdict_ok", "error_mm", "seconds", *by} - set(robust.columns)
    if missing:
        raise ValueError(f"robust must hold robustness_sweep rows; missing columns {sorted(missing)}")
    flags = robust.assign(refused=~robust["verdict_ok"].astype(bool),
                          wrong_accepted=robust["verdict_ok"].astype(bool) & ~robust["success"].astype(bool))
    return (flags.groupby(list(by), sort=False)
            .agg(poses=("pose", "size"), success_rate=("success", "mean"), refused=("refused", "sum"),
                 wrong_accepted=("wrong_accepted", "sum"), median_error_mm=("error_mm", "median"),
                 median_seconds=("seconds", "median"))
            .reset_index())


def degradation_sweep(levels: Sequence[float], *, pose_model: TransducerModel, render_model: TransducerModel,
                      physical: TransducerModel, views: Sequence[View], seed: int, config: PoseStudyConfig,
                      n_poses: int = 3, mode: str = "fast") -> pd.DataFrame:
    """Focal-point error vs segmentation degradation on the same frames.

    Level ``s`` scales Table I's losses: recall ``1 - s (1 - recall_k)``, precision likewise
    (0 = perfect labels, 1 = Table I). One row per (pose, level).
    """
    base = SegmentationDegradation.paper_table1()
    rows = []
    for i, seq in enumerate(np.random.SeedSequence(seed).spawn(n_poses)):
        rng_pose, rng_scene, rng_render, rng_est = (np.random.default_rng(s) for s in seq.spawn(4))
        scene = random_background(rng_scene, config.background)
        T = _experiment_pose(rng_pose, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        frames = [render_frame(render_model, T, v, rng=rng_render, physical=physical, background=scene,
                               photons_per_pixel=config.photons_per_pixel, n_splats=config.n_splats,
                               splat_sigma_mm=config.splat_sigma_mm) for v in views]
        truth = _bubble_centre(physical, T, config.bubble_offset_mm)
        for s in levels:
            if not (0 <= s < 1 / (1 - min(base.recall.values())) ):
                raise ValueError(f"levels must keep recall above 0; got level {s!r}")
            deg = None if s == 0 else SegmentationDegradation(
                recall={k: 1 - s * (1 - v) for k, v in base.recall.items()},
                precision={k: max(1e-3, 1 - s * (1 - v)) for k, v in base.precision.items()})
            row = {"pose": i, "level": s}
            try:
                res = estimate_pose(frames, pose_model, segmenter=OracleSegmenter(deg),
                                    orientation=OracleOrientation(), rng=np.random.default_rng(rng_est.integers(2**63)),
                                    mode=mode)
                row.update(error_mm=float(np.linalg.norm(res.focal_point_mm - truth)), ok=True)
            except PoseEstimationError:
                row.update(error_mm=np.nan, ok=False)
            rows.append(row)
    return pd.DataFrame(rows)


def noise_sweep(photons_per_pixel: Sequence[float], *, pose_model: TransducerModel, render_model: TransducerModel,
                physical: TransducerModel, views: Sequence[View], seed: int, config: PoseStudyConfig,
                segmenter: Segmenter, orientation: OrientationSource | None = None, n_poses: int = 3,
                mode: str = "fast") -> pd.DataFrame:
    """Focal-point error vs fluoroscopic dose: the same poses, scenes and splats rendered at each
    photon count (lower = noisier), segmented by ``segmenter``; one row per (pose, level).

    Only a segmenter that reads the image (the U-Net) sees the noise: the oracle segmenter reads
    the reference labels, so its errors do not change with the dose.
    """
    if not photons_per_pixel or any(not (np.isfinite(p) and p > 0) for p in photons_per_pixel):
        raise ValueError(f"photons_per_pixel must hold positive photon counts, got {photons_per_pixel!r}")
    orientation = OracleOrientation() if orientation is None else orientation
    rows = []
    for i, seq in enumerate(np.random.SeedSequence(seed).spawn(n_poses)):
        rng_pose, rng_scene, rng_render, rng_est = (np.random.default_rng(s) for s in seq.spawn(4))
        scene = random_background(rng_scene, config.background)
        T = _experiment_pose(rng_pose, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        truth = _bubble_centre(physical, T, config.bubble_offset_mm)
        render_seed, est_seed = rng_render.integers(2**63), rng_est.integers(2**63)
        for photons in photons_per_pixel:
            # The same splat and noise streams at every level: only the dose differs.
            rng = np.random.default_rng(render_seed)
            frames = [render_frame(render_model, T, v, rng=rng, physical=physical, background=scene,
                                   photons_per_pixel=float(photons), n_splats=config.n_splats,
                                   splat_sigma_mm=config.splat_sigma_mm) for v in views]
            row = {"pose": i, "photons_per_pixel": float(photons)}
            try:
                res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                    rng=np.random.default_rng(est_seed), mode=mode)
                row.update(error_mm=float(np.linalg.norm(res.focal_point_mm - truth)), ok=True)
            except PoseEstimationError:
                row.update(error_mm=np.nan, ok=False)
            rows.append(row)
    return pd.DataFrame(rows)
