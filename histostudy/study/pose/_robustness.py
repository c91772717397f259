"""Beyond the paper: how often the initialisation of §II-B.4 finds the pose from anywhere in the
paper's training ranges (§II-B.2); one row per (random pose, initialisation). The pose task stays
at module level because a cluster's workers run it (:func:`histostudy.core.run_sweep`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from histostudy.core import SweepExecutor, run_sweep
from histostudy.imaging import View, random_background, render_frame
from histostudy.learning import OracleOrientation, OrientationSource, Segmenter
from histostudy.pose import PoseConfig, PoseEstimationError, estimate_pose
from histostudy.transducer import Feature, TransducerModel, half_turn_symmetric

from .experiments import PoseStudyConfig
from .geometry import (
    bubble_cloud_centre_mm,
    random_pose_in_views,
    rotation_error_modulo_symmetry_deg,
    sweep_visible_points,
)
from .segmentations import SegmentationCache

__all__ = ["robustness_summary", "robustness_sweep"]


def robustness_sweep(n_poses: int, *, pose_model: TransducerModel, render_model: TransducerModel,
                     physical: TransducerModel, views: Sequence[View], seed: int, config: PoseStudyConfig,
                     inits: Sequence[str] = ("robust", "paper"), mode: str = "fast",
                     success_mm: float = 2.0, segmenter: Segmenter | None = None,
                     orientation: OrientationSource | None = None, workers: int | None = None,
                     executor: SweepExecutor | str | None = None, stage_sets: dict | None = None,
                     pose_options: PoseConfig | None = None) -> pd.DataFrame:
    """Initialisation success over random poses in the paper's training ranges (§II-B.2, §II-B.4).

    Each pose shows the focal point and the transducer's centre in every view (the transducer seen,
    at least half of it); backgrounds from the paper's evaluation mix (abdomen and phantom). Every
    pose draws from its own child of ``SeedSequence(seed)``, so the rows are the same whatever runs
    them (but ``seconds``).

    Args:
        n_poses: random poses.
        pose_model: the digital model the cost uses.
        render_model: the model frames are rendered from.
        physical: the physical transducer.
        views: the C-arm views.
        seed: the sweep's integer seed.
        config: the study's parameters (rendering, oracle degradation, bubble offset).
        inits: the initialisations compared (``"robust"``, ``"paper"``).
        mode: the refinement mode.
        success_mm: success: an accepted estimate with a focal error below this (mm).
        segmenter: the segmentation stage; None: the config's oracle.
        orientation: the orientation source; None: the oracle with the paper's angle MAE.
        workers: > 1: the older spelling of ``executor="local:<workers>"``; 1: this process.
        executor: what runs the poses (:func:`histostudy.core.run_sweep`: ``"sequential"``,
            ``"local:<n>"``, ``"tcp://host:port"``, a :class:`~histostudy.core.SweepExecutor`; None:
            ``$HISTOSTUDY_SCHEDULER``, else sequential).
        stage_sets: name -> ``dict(segmenter=..., orientation=..., inits=...)`` (None or a missing
            key: as above): several sets of stages run on each pose's frames, rendered once; each set
            draws as a sweep of its own would, so its rows equal that sweep's (but ``seconds``), and a
            segmenter that draws nothing (``uses_rng = False``) segments a frame once for every set.
            The rows gain the column ``stages``. None: the one set of ``segmenter``, ``orientation``
            and ``inits``, without the column.
        pose_options: the estimates' :class:`~histostudy.pose.PoseConfig` (its ``mode``, ``init`` and
            ``raise_on_failure`` set by the sweep); None: the defaults. E.g. a verdict's bounds set
            out of reach, so that every estimate's figures are measured and none refused by them.

    Returns:
        One row per (pose, init): ``error_mm``, ``rotation_error_deg`` (up to a half turn where the
        model looks the same after one), ``half_turned``, ``verdict_ok``, ``success``, ``failure``,
        per view ``rms_<view>``, ``body_rms_<view>``, ``unexplained_<view>``, ``disagreement_mm_<view>``,
        ``gain_px2_<view>`` and ``relative_gain_<view>`` (px, fraction, mm, px², ratio: the verdict's
        figures; NaN where not reached), ``seconds``.

    Raises:
        ValueError: ``workers`` not an integer >= 1, or given with ``executor``.
    """
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
        if executor is not None:
            raise ValueError(f"give workers or executor, not both (workers={workers!r}, executor={executor!r})")
        executor = SweepExecutor("local", n_workers=int(workers)) if workers > 1 else "sequential"
    # a set's entries are of mixed types (stages and a sequence of names), as the caller's stage_sets
    one: dict[str, Any] = {"segmenter": segmenter, "orientation": orientation, "inits": inits}
    sets = [(None, one)] if stage_sets is None else [(name, {**one, **given}) for name, given in stage_sets.items()]
    if not sets or any(set(given) - set(one) for _, given in sets):
        raise ValueError(f"stage_sets must map names to dicts of segmenter, orientation and inits, got {stage_sets!r}")
    resolved: list[tuple[str | None, Segmenter, OrientationSource, tuple[str, ...]]] = [
        (name, config.segmenter() if given["segmenter"] is None else given["segmenter"],
         OracleOrientation() if given["orientation"] is None else given["orientation"], tuple(given["inits"]))
        for name, given in sets]
    if pose_options is not None and not isinstance(pose_options, PoseConfig):
        raise TypeError(f"pose_options must be a histostudy.pose.PoseConfig or None, got {type(pose_options).__name__}")
    shared = dict(pose_model=pose_model, render_model=render_model, physical=physical, views=list(views),
                  config=config, stage_sets=resolved, mode=mode, success_mm=success_mm,
                  half_turn=half_turn_symmetric(pose_model), pose_options=pose_options)
    per_pose = run_sweep(_sweep_pose, range(n_poses), seed=seed, executor=executor, shared=shared)
    return pd.DataFrame([row for rows in per_pose for row in rows])


def _sweep_pose(i: int, seq: np.random.SeedSequence, *, pose_model, render_model, physical, views, config,
                stage_sets, mode, success_mm, half_turn, pose_options=None) -> list[dict]:
    seq_pose, seq_scene, seq_render, seq_est = seq.spawn(4)
    rng_pose, rng_scene, rng_render = (np.random.default_rng(s) for s in (seq_pose, seq_scene, seq_render))
    T = random_pose_in_views(rng_pose, views, visible_points_mm=sweep_visible_points(pose_model))
    scene = random_background(rng_scene, "mixed")
    frames = [render_frame(render_model, T, v, rng=rng_render, physical=physical, background=scene,
                           **config.frame_kwargs()) for v in views]
    truth = bubble_cloud_centre_mm(physical, T, config.bubble_offset_mm)
    segmented: dict[int, SegmentationCache] = {}  # one per segmenter: a set's estimates share its labels
    rows = []
    for name, segmenter, orientation, inits in stage_sets:
        if id(segmenter) not in segmented:
            segmented[id(segmenter)] = SegmentationCache(segmenter, max_frames=len(views))
        segmenter = segmented[id(segmenter)]
        rng_est = np.random.default_rng(seq_est)  # each set draws as a sweep of its own
        rows += _estimates(i, frames, T, truth, scene, name, segmenter, orientation, inits, rng_est,
                           pose_model=pose_model, views=views, mode=mode, success_mm=success_mm, half_turn=half_turn,
                           pose_options=pose_options)
    return rows


def _estimates(i, frames, T, truth, scene, name, segmenter, orientation, inits, rng_est, *, pose_model, views, mode,
               success_mm, half_turn, pose_options=None) -> list[dict]:
    """The rows of one pose's estimates with one set of stages, an initialisation each."""
    rows = []
    for init in inits:
        row = {"pose": i, "init": init, "scene": scene.kind}
        t0 = time.perf_counter()
        try:
            res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                rng=np.random.default_rng(rng_est.integers(2**63)), options=pose_options, mode=mode,
                                init=init, raise_on_failure=False)
        except PoseEstimationError as exc:  # nothing segmented in a view: no pose at all
            row.update(error_mm=np.nan, verdict_ok=False, success=False, failure=str(exc)[:120])
        else:
            err = float(np.linalg.norm(res.focal_point_mm - truth))
            rotation_deg, half_turned = rotation_error_modulo_symmetry_deg(
                res.T_carm_transducer, T, half_turn=half_turn)
            v = res.verdict
            row.update(error_mm=err, rotation_error_deg=rotation_deg, half_turned=half_turned,
                       verdict_ok=v.ok, success=v.ok and err < success_mm,
                       failure="" if v.ok else ("implausible pose: " + "; ".join(v.reasons))[:200])
            for view in views:
                view_name = view.name
                row[f"rms_{view_name}"] = v.rms_distance_px.get(view_name, np.nan)
                row[f"body_rms_{view_name}"] = v.class_rms_distance_px.get(view_name, {}).get(
                    Feature.TRANSDUCER.name.lower(), np.nan)
                row[f"unexplained_{view_name}"] = v.unexplained_fraction.get(view_name, np.nan)
                row[f"disagreement_mm_{view_name}"] = v.view_disagreement_mm.get(view_name, np.nan)
                row[f"gain_px2_{view_name}"] = v.view_gain_px2.get(view_name, np.nan)
                row[f"relative_gain_{view_name}"] = v.view_relative_gain.get(view_name, np.nan)
        row["seconds"] = time.perf_counter() - t0
        if name is not None:
            row["stages"] = name
        rows.append(row)
    return rows


def robustness_summary(robust: pd.DataFrame, by: Sequence[str] = ("init",)) -> pd.DataFrame:
    """Per group of :func:`robustness_sweep` rows: how often the initialisation succeeds.

    Args:
        robust: :func:`robustness_sweep`'s rows.
        by: the columns to group by.

    Returns:
        One row per group: poses, success rate, refused (by the verdict), wrong_accepted (accepted
        although off by ``success_mm`` or more: a robot would be sent there), median error (mm) and
        median seconds.

    Raises:
        ValueError: ``robust`` lacks a column the summary reads.
    """
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
