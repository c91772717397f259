"""Beyond the paper: focal-point error vs segmentation quality (:func:`degradation_sweep`, Table I's
losses scaled) and vs fluoroscopic dose (:func:`noise_sweep`, §II-B.2's Poisson noise); errors in
mm, C-arm frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from histostudy.imaging import View, random_background, render_frame
from histostudy.learning import (
    OracleOrientation,
    OracleSegmenter,
    OrientationSource,
    SegmentationDegradation,
    Segmenter,
)
from histostudy.pose import PoseEstimationError, estimate_pose
from histostudy.transducer import TransducerModel

from .experiments import PoseStudyConfig
from .geometry import bubble_cloud_centre_mm, experiment_pose

__all__ = ["degradation_sweep", "noise_sweep"]


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
        T = experiment_pose(rng_pose, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        frames = [render_frame(render_model, T, v, rng=rng_render, physical=physical, background=scene,
                               **config.frame_kwargs()) for v in views]
        truth = bubble_cloud_centre_mm(physical, T, config.bubble_offset_mm)
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
        T = experiment_pose(rng_pose, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        truth = bubble_cloud_centre_mm(physical, T, config.bubble_offset_mm)
        render_seed, est_seed = rng_render.integers(2**63), rng_est.integers(2**63)
        for photons in photons_per_pixel:
            # The same splat and noise streams at every level: only the dose differs.
            rng = np.random.default_rng(render_seed)
            frames = [render_frame(render_model, T, v, rng=rng, physical=physical, background=scene,
                                   **{**config.frame_kwargs(), "photons_per_pixel": float(photons)}) for v in views]
            row = {"pose": i, "photons_per_pixel": float(photons)}
            try:
                res = estimate_pose(frames, pose_model, segmenter=segmenter, orientation=orientation,
                                    rng=np.random.default_rng(est_seed), mode=mode)
                row.update(error_mm=float(np.linalg.norm(res.focal_point_mm - truth)), ok=True)
            except PoseEstimationError:
                row.update(error_mm=np.nan, ok=False)
            rows.append(row)
    return pd.DataFrame(rows)
