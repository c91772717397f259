"""Beyond the paper: the pose pipeline on frames of an independent projector, RTK's Joseph ray
caster on the voxelised physical transducer (optional ``histostudy[rtk]``), beside the study's own
splatting renderer on the same poses, scenes and noise (docs/pose-study.md).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pandas as pd

from histostudy.imaging import View, random_background, render_frame
from histostudy.pose import PoseEstimationError, estimate_pose
from histostudy.transducer import TransducerModel

from .experiments import PoseStudyConfig, experiment_setups
from .geometry import bubble_cloud_centre_mm, random_pose_in_views, sweep_visible_points

__all__ = ["PROJECTORS", "comparison_poses", "projector_comparison", "projector_summary"]

#: The projectors compared: the project's splatting renderer and RTK's Joseph ray caster.
PROJECTORS = ("splatting", "rtk-joseph")


def comparison_poses(config: PoseStudyConfig, seed: int, *, n_study: int, n_random: int, views: Sequence[View],
                     pose_model: TransducerModel) -> list[dict]:
    """The poses of the comparison: the centre poses of the first ``n_study`` experiments of the
    pose study (:func:`~histostudy.study.pose.experiments.experiment_setups`, their phantom scenes),
    then ``n_random`` random poses in the paper's training ranges with the transducer centre and
    focal point in every view (mixed backgrounds), as the robustness sweep draws them. Each item:
    ``{"kind", "index", "T", "scene"}``."""
    for name, value in (("n_study", n_study), ("n_random", n_random)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
    poses = []
    if n_study:
        setups = experiment_setups(replace(config, n_experiments=n_study), seed)
        for exp in setups[:n_study]:
            poses.append({"kind": "study", "index": exp.experiment, "T": exp.T_true["centre"], "scene": exp.scene})
    visible = sweep_visible_points(pose_model)
    for i, seq in enumerate(np.random.SeedSequence([seed, 7]).spawn(n_random)):
        rng_pose, rng_scene = (np.random.default_rng(s) for s in seq.spawn(2))
        T = random_pose_in_views(rng_pose, views, visible_points_mm=visible)
        poses.append({"kind": "random", "index": i, "T": T, "scene": random_background(rng_scene, "mixed")})
    return poses


def projector_comparison(poses: Sequence[dict], *, pose_model: TransducerModel, render_model: TransducerModel,
                         physical: TransducerModel, views: Sequence[View], config: PoseStudyConfig, seed: int,
                         segmenter, orientation, voxel_mm: float = 0.5, mode: str = "fast",
                         success_mm: float = 2.0) -> pd.DataFrame:
    """One row per (pose, projector): focal error (mm) against the physical transducer's bubble
    centre, whether the verdict accepted the pose, success (accepted and < ``success_mm``), and
    the seconds of rendering and of estimation.

    Both projectors get the same pose, scene, photon count and noise stream; the splatting
    renderer projects ``physical`` as the study does, RTK its voxelisation at ``voxel_mm``. The
    estimation's random stream is the same for both.
    """
    from histostudy.imaging import render_frame_rtk

    rows = []
    for p, seq in zip(poses, np.random.SeedSequence([seed, 11]).spawn(len(poses))):
        noise_seed, est_seed = seq.generate_state(2)
        truth = bubble_cloud_centre_mm(physical, p["T"], config.bubble_offset_mm)
        for projector in PROJECTORS:
            rng = np.random.default_rng(noise_seed)
            t0 = time.perf_counter()
            if projector == "splatting":
                frames = [render_frame(render_model, p["T"], v, rng=rng, physical=physical, background=p["scene"],
                                       **config.frame_kwargs()) for v in views]
            else:
                frames = [render_frame_rtk(render_model, physical, p["T"], v, rng=rng, background=p["scene"],
                                           photons_per_pixel=config.photons_per_pixel, voxel_mm=voxel_mm)
                          for v in views]
            render_s = time.perf_counter() - t0
            row = {"kind": p["kind"], "pose": p["index"], "projector": projector, "render_seconds": render_s}
            t0 = time.perf_counter()
            try:
                res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation, mode=mode,
                                    rng=np.random.default_rng(est_seed))
                error, ok, failure = float(np.linalg.norm(res.focal_point_mm - truth)), True, ""
            except PoseEstimationError as exc:
                error = float(np.linalg.norm(exc.result.focal_point_mm - truth)) if exc.result is not None else np.nan
                ok, failure = False, str(exc)[:120]
            row.update(error_mm=error, verdict_ok=ok, success=ok and error < success_mm,
                       estimate_seconds=time.perf_counter() - t0, failure=failure)
            rows.append(row)
    return pd.DataFrame(rows)


def projector_summary(rows: pd.DataFrame) -> pd.DataFrame:
    """Per pose kind and projector: n, successes, refusals, accepted off by >= 2 mm, mean and median
    focal error of the accepted estimates (mm); and, per pose kind, the mean of the per-pose
    differences (RTK minus splatting) over poses both accepted (``paired_difference_mm``)."""
    out = []
    for (kind, projector), g in rows.groupby(["kind", "projector"], sort=False):
        accepted = g[g["verdict_ok"]]
        out.append({"kind": kind, "projector": projector, "n": int(len(g)), "success": int(g["success"].sum()),
                    "refused": int((~g["verdict_ok"]).sum()),
                    "accepted_wrong": int((g["verdict_ok"] & ~g["success"]).sum()),
                    "mean_error_mm": float(accepted["error_mm"].mean()) if len(accepted) else np.nan,
                    "median_error_mm": float(accepted["error_mm"].median()) if len(accepted) else np.nan})
    summary = pd.DataFrame(out)
    paired = rows[rows["verdict_ok"]].pivot_table(index=["kind", "pose"], columns="projector", values="error_mm")
    diffs = {}
    if set(PROJECTORS) <= set(paired.columns):
        both = paired.dropna()
        for kind, g in both.groupby(level="kind"):
            diffs[kind] = float((g["rtk-joseph"] - g["splatting"]).mean())
    summary["paired_difference_mm"] = summary["kind"].map(diffs)
    return summary
