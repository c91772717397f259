"""Notebook 04's phantom experiments of Table II (§II-D, §II-E.3, §III): draw, render, estimate.

Each experiment places the transducer with its focal point near the phantom centre, then moves
it by ``r`` (10 or 12.5 mm: a 20 or 25 mm treatment sphere) along the robot's axes to the six
margin points (top/bottom = TB, left/right = LR, front/back = depth). At the centre and each
margin a biplane pair is rendered (the physical transducer, a phantom scene, Poisson noise) and
the pose is estimated (:func:`histostudy.pose.estimate_pose`). Errors are decomposed along the
transducer's depth, TB and LR axes (:func:`~histostudy.study.pose._geometry.transducer_axes`), as §II-E.

The robot's axes are taken along the transducer's own LR, TB and depth axes at the centre pose
(the transducer hanging from the UR5e's flange with its axes along the base axes), so that the
radius per direction of Table II is the half distance between opposite margin predictions.
C-arm (CBCT) frame, mm; rotation errors in degrees.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from histostudy.imaging import Anatomy, View, random_background, render_frame
from histostudy.learning import OracleOrientation, OrientationSource, Segmenter
from histostudy.pose import PoseEstimationError, estimate_pose
from histostudy.transducer import TransducerModel

from ._config import PoseStudyConfig
from ._geometry import (
    DIRECTIONS,
    axial_symmetric_rotation_error_deg,
    bubble_cloud_centre_mm,
    experiment_pose,
    margin_positions,
    transducer_axes,
)

__all__ = ["PoseExperiment", "draw_experiments", "experiment_setups", "run_pose_study"]


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


def draw_experiments(config: PoseStudyConfig, seed: int):
    """Yield ``(PoseExperiment, rng_render, rng_est, rng_cbct)`` per experiment.

    The one place the experiments are drawn: :func:`run_pose_study` renders and estimates from
    them and :func:`cbct_reference` treats and scans the same set-ups. Streams per experiment:
    children 0-4 of its seed sequence (pose, scene, render, robot, estimation); child 5 is the CBCT
    reference's (treatment positioning noise, CBCT noise), a stream of its own so that the
    reference changes no other draw.
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
    """The experiments :func:`run_pose_study` runs for ``config`` and ``seed`` (no rendering)."""
    return [exp for exp, *_ in draw_experiments(config, seed)]


def run_pose_study(config: PoseStudyConfig, *, pose_model: TransducerModel, render_model: TransducerModel,
                   physical: TransducerModel, views: Sequence[View], seed: int,
                   segmenter: Segmenter | None = None, orientation: OrientationSource | None = None,
                   progress: Callable[[str], None] | None = None, estimator_views: Sequence[View] | None = None,
                   experiments: Sequence[int] | None = None, acquisition_views=None) -> pd.DataFrame:
    """Run the experiments; one row per (experiment, position, mode, maps), plus tracking rows.

    Columns: experiment, radius_mm, position, mode, maps, the true and predicted focal points
    (``true_*``, ``pred_*``, world mm), the error along depth/TB/LR of the experiment's centre
    pose (``err_depth`` ...), ``err_euclidean``, ``rotation_error_deg`` (modulo the transducer's
    half-turn symmetry), cost, iterations, seconds per stage (``s_*``), ``ok`` and the failure
    text (a failed estimate keeps NaN predictions). With ``config.track``, rows of mode
    ``"track"`` hold the margin poses re-estimated from the centre's estimate (warm start).

    ``segmenter`` and ``orientation`` default to the config's oracles (Table I degradation and
    the paper's angle MAE); pass learned ones to run the study on them.

    ``views`` make the frames (the C-arm's true geometry); ``estimator_views``, when given, are
    what the estimator is told (a lab's calibration, :mod:`~histostudy.study.budget._sources`);
    ``acquisition_views(experiment, acquisition, views)``, when given, those it is told at each
    acquisition (0 the centre, then the margins in order: a lab's per-acquisition C-arm
    reproducibility), the frames unchanged.
    ``experiments``: run only these experiment indices (the others are drawn, not rendered, so
    each keeps its numbers).
    """
    rows = []
    estimator_views = list(views) if estimator_views is None else list(estimator_views)
    if len(estimator_views) != len(views):
        raise ValueError(f"estimator_views must hold one view per frame view ({len(views)}), got {len(estimator_views)}")
    wanted = None if experiments is None else {int(e) for e in experiments}
    segmenter = config.segmenter() if segmenter is None else segmenter
    orientation = OracleOrientation() if orientation is None else orientation
    predicted_offset = config.predicted_bubble_offset_mm
    for exp, rng_render, rng_est, _ in draw_experiments(config, seed):
        if wanted is not None and exp.experiment not in wanted:
            continue
        e, radius, scene = exp.experiment, exp.radius_mm, exp.scene
        axes = transducer_axes(exp.T_centre)
        centre_estimate = None
        for acquisition, (position, T_true) in enumerate(exp.T_true.items()):
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
                    res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
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
