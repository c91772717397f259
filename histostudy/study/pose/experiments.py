"""Notebook 04's experiment layer, shared by notebooks 05 and 07: the pose study's parameters
(:class:`PoseStudyConfig`), its segmentation and orientation stages (:func:`study_stages`) and the
phantom experiments of Table II drawn, rendered and estimated (:func:`run_pose_study`; §II-D,
§II-E.3). C-arm (CBCT) frame, mm; rotation errors in degrees (docs/pose-study.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from histostudy.imaging import Anatomy, FrameRenderConfig, View, random_background, render_frame
from histostudy.learning import OracleOrientation, OracleSegmenter, OrientationSource, Segmenter
from histostudy.pose import MAP_KINDS, PoseEstimationError, estimate_pose, learned_stage_shortfalls
from histostudy.transducer import TransducerModel

from .geometry import (
    DIRECTIONS,
    axial_symmetric_rotation_error_deg,
    bubble_cloud_centre_mm,
    experiment_pose,
    margin_positions,
    transducer_axes,
)
from .segmentations import SegmentationCache

__all__ = ["PoseExperiment", "PoseStudyConfig", "StudyStages", "draw_experiments", "experiment_setups",
           "run_pose_study", "study_stages"]


@dataclass(frozen=True)
class PoseStudyConfig(FrameRenderConfig):
    """Parameters of the pose-estimation study (defaults: the standard profile's); a plain dataclass of
    the experiment layer, not a notebook's section config (notebook 04's is
    :class:`~histostudy.study.pose.PoseSectionConfig`, whose ``study_config()`` makes this).

    Args:
        photons_per_pixel: dose, Poisson photons per unattenuated pixel (§II-B.2;
            :class:`~histostudy.imaging.FrameRenderConfig`, checks included).
        n_splats: splats per model point.
        splat_sigma_mm: splat SD (mm).
        background: the scene behind the transducer (the paper's pose studies: ``"phantom"``).
        n_experiments: phantom experiments (paper: 10).
        margin_mm: radii ``r`` drawn per experiment (mm; paper: 10 or 12.5, spheres of 2.0 or 2.5 cm).
        degradation: ``"table1"`` (oracle errs as the paper's U-Net, Table I) or ``"none"``.
        modes: refinement modes run on the same frames (``"paper"``, ``"fast"``).
        distance_maps: map kinds run on the same frames (``"occlusion_aware"``, ``"per_class"``, see
            :func:`histostudy.pose.estimate_pose`); every mode runs with every kind.
        track: also re-estimate each margin pose warm-started from the centre's estimate (fast mode).
        tilt_sd_deg: SD of the transducer axis's tilt from vertical, per axis (deg).
        focal_jitter_mm: focal point uniform within ± this of the phantom centre, per axis (mm).
        robot_repeatability_mm: SD of the robot's positioning noise (mm; UR5e: ±0.03).
        bubble_offset_mm: the bubble cloud's offset from the acoustic focal point (3, transducer frame, mm).
        assumed_bubble_offset_mm: the offset the prediction adds to the estimated focal point
            (transducer frame, mm); None: ``bubble_offset_mm``, known as after a test pulse (a lab that
            did not calibrate it, :class:`~histostudy.study.budget.LabErrorModel`, assumes zeros).

    Raises:
        ValueError: a value out of its range (named), an unknown mode, map kind or degradation.
    """

    n_experiments: int = 10
    margin_mm: tuple = (10.0, 12.5)
    degradation: str = "table1"
    modes: tuple = ("paper", "fast")
    distance_maps: tuple = ("occlusion_aware",)
    track: bool = True
    tilt_sd_deg: float = 10.0
    focal_jitter_mm: float = 5.0
    robot_repeatability_mm: float = 0.01
    bubble_offset_mm: tuple = (0.0, 0.0, 0.0)
    assumed_bubble_offset_mm: tuple | None = None

    def __post_init__(self):
        super().__post_init__()
        for name in ("bubble_offset_mm", "assumed_bubble_offset_mm"):
            value = getattr(self, name)
            if value is not None and (np.shape(value) != (3,) or not np.all(np.isfinite(np.asarray(value, float)))):
                raise ValueError(f"{name} must be 3 finite numbers (transducer frame, mm), got {value!r}")
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

    @property
    def predicted_bubble_offset_mm(self) -> np.ndarray:
        """The offset the prediction adds to the estimated focal point (transducer frame, mm)."""
        offset = self.bubble_offset_mm if self.assumed_bubble_offset_mm is None else self.assumed_bubble_offset_mm
        return np.asarray(offset, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class StudyStages:
    """The segmenter and orientation source a pose study runs on, and why those (:func:`study_stages`).

    Args:
        segmenter: the segmentation stage the estimates run on.
        orientation: the orientation source they run on.
        learned: whether those are the shipped networks.
        why: the report's sentence saying which and why.
        shipped_segmenter: the shipped U-Net considered (None when missing or not asked for).
        shipped_orientation: the shipped orientation source considered (likewise).
    """

    segmenter: Segmenter
    orientation: OrientationSource
    learned: bool
    why: str
    shipped_segmenter: Segmenter | None = None
    shipped_orientation: OrientationSource | None = None


def study_stages(config, learned: bool = True, *, segmenter=None, orientation=None) -> StudyStages:
    """The stages of a study's pose estimates: learned by default, the oracles where the learned ones
    fall short of :data:`histostudy.pose.LEARNED_STAGE_REQUIREMENTS`.

    Args:
        config: a :class:`PoseStudyConfig`, or any study config whose ``segmenter()`` gives its oracle
            (notebook 05's :class:`~histostudy.study.targeting.setup.TargetingStudyConfig`).
        learned: try the shipped networks; False: the config's oracles (Table I degradation, the
            paper's angle MAE).
        segmenter: the U-Net to judge; None: :func:`histostudy.learning.default_segmenter`.
        orientation: the orientation source to judge; None: :func:`histostudy.pose.default_orientation`.

    Returns:
        The :class:`StudyStages`, its ``why`` saying which and why.
    """
    oracles = (config.segmenter(), OracleOrientation())
    if not learned:
        return StudyStages(*oracles, learned=False, why="oracle stages: the learned stages are disabled "
                           "(learned_stages = False)")
    if segmenter is None or orientation is None:
        from histostudy.learning import default_segmenter
        from histostudy.pose import default_orientation

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



@dataclass(frozen=True, eq=False)
class PoseExperiment:
    """One experiment's set-up as :func:`run_pose_study` draws it.

    Args:
        experiment: its index.
        radius_mm: the treatment sphere's radius ``r`` (mm; the robot's move to each margin).
        scene: the phantom set-up behind the transducer.
        T_centre: the commanded centre pose ``T_carm_transducer`` (4x4, mm).
        T_true: per position (``"centre"``, then the six margins) the reached pose (4x4, mm), the
            robot's repeatability noise included.
    """

    experiment: int
    radius_mm: float
    scene: Anatomy
    T_centre: np.ndarray
    T_true: dict


def draw_experiments(config: PoseStudyConfig, seed: int):
    """Yield each experiment's set-up and its random streams: the one place the experiments are drawn.

    :func:`run_pose_study` renders and estimates from them and
    :func:`~histostudy.study.pose.reference.cbct_reference` treats and scans the same set-ups.
    Streams per experiment: children 0-4 of its seed sequence (pose, scene, render, robot,
    estimation); child 5 is the CBCT reference's, so that the reference changes no other draw.

    Args:
        config: the study's parameters.
        seed: the study's integer seed.

    Returns:
        An iterator of ``(PoseExperiment, rng_render, rng_est, rng_cbct)``.
    """
    for e, seq in enumerate(np.random.SeedSequence(seed).spawn(config.n_experiments)):
        rng_pose, rng_scene, rng_render, rng_robot, rng_est, rng_cbct = (np.random.default_rng(s) for s in seq.spawn(6))
        radius = float(rng_pose.choice(config.margin_mm))
        scene = random_background(rng_scene, config.background)
        centre = scene.meta.get("phantom_center_mm", np.zeros(3))
        T_centre = experiment_pose(rng_pose, config, centre)
        T_true = {}
        for position, T_nominal in margin_positions(T_centre, radius).items():
            T = T_nominal.copy()
            T[:3, 3] += rng_robot.normal(0, config.robot_repeatability_mm, 3)
            T_true[position] = T
        yield PoseExperiment(e, radius, scene, T_centre, T_true), rng_render, rng_est, rng_cbct


def experiment_setups(config: PoseStudyConfig, seed: int) -> list[PoseExperiment]:
    """The experiments :func:`run_pose_study` runs for ``config`` and ``seed``, without rendering.

    Args:
        config: the study's parameters.
        seed: the study's integer seed.

    Returns:
        One :class:`PoseExperiment` per experiment.
    """
    return [exp for exp, *_ in draw_experiments(config, seed)]


def run_pose_study(config: PoseStudyConfig, *, pose_model: TransducerModel, render_model: TransducerModel,
                   physical: TransducerModel, views: Sequence[View], seed: int,
                   segmenter: Segmenter | None = None, orientation: OrientationSource | None = None,
                   progress: Callable[[str], None] | None = None, estimator_views: Sequence[View] | None = None,
                   experiments: Sequence[int] | None = None, acquisition_views=None,
                   centre_only: bool = False) -> pd.DataFrame:
    """Run the experiments of Table II (§II-D): render each position and estimate the pose.

    Args:
        config: the study's parameters.
        pose_model: the digital model the cost uses.
        render_model: the model frames are rendered from.
        physical: the physical transducer (the frames and the bubble clouds).
        views: the views that make the frames (the C-arm's true geometry).
        seed: the study's integer seed (:func:`draw_experiments`).
        segmenter: the segmentation stage; None: the config's oracle (Table I degradation).
        orientation: the orientation source; None: the oracle with the paper's angle MAE.
        progress: called with a line per position; None: silent.
        estimator_views: the views the estimator is told (a lab's calibration); None: ``views``.
        experiments: run only these experiment indices (the others are drawn, not rendered, so each
            keeps its numbers); None: all.
        acquisition_views: ``(experiment, acquisition, views) -> views`` told at each acquisition
            (0 the centre, then the margins; a lab's per-acquisition C-arm reproducibility); None: as given.
        centre_only: acquire only each experiment's centre, the first acquisition: its rows are those
            of the whole run (no draw of the margins comes before them); the margins are neither
            rendered nor estimated (for a figure of the centre alone, as notebook 07's ranges).

    Returns:
        One row per (experiment, position, mode, maps), plus ``"track"`` rows with ``config.track``:
        experiment, radius_mm, position, mode, maps, ``true_*`` and ``pred_*`` (C-arm mm), ``err_depth``,
        ``err_tb``, ``err_lr`` (along the centre pose's axes, mm), ``err_euclidean``,
        ``rotation_error_deg`` (modulo the half-turn symmetry), cost, iterations, ``s_*`` (seconds per
        stage), ``ok`` and ``failure`` (a failed estimate keeps NaN predictions).

    Raises:
        ValueError: ``estimator_views`` of another length than ``views``, or ``centre_only`` not a bool.
    """
    if not isinstance(centre_only, bool):
        raise ValueError(f"centre_only must be True or False, got {centre_only!r}")
    rows = []
    estimator_views = list(views) if estimator_views is None else list(estimator_views)
    if len(estimator_views) != len(views):
        raise ValueError(f"estimator_views must hold one view per frame view ({len(views)}), "
                         f"got {len(estimator_views)}")
    wanted = None if experiments is None else {int(e) for e in experiments}
    segmenter = config.segmenter() if segmenter is None else segmenter
    # an acquisition's variants segment its frames once (exact: SegmentationCache) where the labels
    # depend on the frame alone: a segmenter that draws meets another Generator state each variant.
    # A caller's cache is used as it is, so that its estimates can be shared too (pose.shared_estimates)
    segmented = segmenter
    if not isinstance(segmenter, SegmentationCache) and not getattr(segmenter, "uses_rng", True):
        segmented = SegmentationCache(segmenter, max_frames=2 * len(views))
    orientation = OracleOrientation() if orientation is None else orientation
    predicted_offset = config.predicted_bubble_offset_mm
    for exp, rng_render, rng_est, _ in draw_experiments(config, seed):
        if wanted is not None and exp.experiment not in wanted:
            continue
        e, radius, scene = exp.experiment, exp.radius_mm, exp.scene
        axes = transducer_axes(exp.T_centre)
        centre_estimate = None
        for acquisition, (position, T_true) in enumerate(exp.T_true.items()):
            if centre_only and acquisition > 0:
                break
            told = estimator_views if acquisition_views is None else acquisition_views(e, acquisition, estimator_views)
            frames = [render_frame(render_model, T_true, v, rng=rng_render, physical=physical, background=scene,
                                   **config.frame_kwargs()).with_view(given)
                      for v, given in zip(views, told)]
            truth = bubble_cloud_centre_mm(physical, T_true, config.bubble_offset_mm)
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
                    res = estimate_pose(frames, pose_model, segmenter=segmented, orientation=orientation,
                                        rng=rng_mode, **kwargs)
                    if position == "centre" and (mode, maps) == config.variants[0]:
                        centre_estimate = res.T_carm_transducer
                    pred = res.focal_point_mm + res.T_carm_transducer[:3, :3] @ predicted_offset
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
