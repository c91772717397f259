"""A campaign network measured on held-out frames as the study measures the shipped one: the U-Net
by Table I's per-class precision, recall and IoU (notebook 02), the VGG19 by §III's azimuth and
elevation MAE and the direction error (notebook 03); and two networks' figures on the same frames
compared frame by frame."""

from __future__ import annotations

import numpy as np

from histostudy.learning import HybridFrames, LearnedOrientation, RenderConfig, UNetRunner

from ..orientation import angle_table, direction_error_summary, evaluate_orientation
from ..segmentation import evaluate_segmentation
from ..stats import paired_comparison

__all__ = ["compare_held_out", "evaluate_held_out"]

_SEGMENTATION_CLASSES = ("transducer", "outer_boundary", "inner_boundary", "gaps", "screws")


def evaluate_held_out(task: str, weights, *, seed: int, n_frames: int, cache_dir, render: dict | None = None,
                      workers: int = 1) -> dict:
    """The network of ``weights`` on ``n_frames`` frames of split ``eval`` at ``seed``.

    Args:
        task: ``"segmentation"`` or ``"orientation"``.
        weights: the checkpoint (``.safetensors`` beside its manifest).
        seed: the frames' seed (draw it after the network's last change).
        n_frames: how many frames.
        cache_dir: the frame cache (the frames are rendered into it, in ``workers`` processes).
        render: :class:`~histostudy.learning.RenderConfig` arguments (default: the study's frames).
        workers: rendering processes.

    Returns:
        ``{"seed", "frames", "render_key"}`` and, for segmentation, ``per_class``: class ->
        ``{precision, recall, iou}`` (percent, mean over frames as Table I, NaN-skipping) and
        ``global_accuracy``; for orientation ``azimuth_mae_deg``, ``elevation_mae_deg`` (§III),
        ``direction_median_deg``, ``direction_p90_deg`` and ``misread_fraction`` (> 30 deg).
        ``per_frame`` holds what :func:`compare_held_out` pairs: each class's IoU per frame
        (percent, NaN where undefined), or ``direction_error_deg`` per frame.

    Raises:
        ValueError: an unknown task, or weights that fail their checks.
    """
    frames = HybridFrames("eval", seed, RenderConfig(**(render or {})), cache_dir=cache_dir)
    frames.prerender(n_frames, workers=workers)
    out = {"seed": int(seed), "frames": int(n_frames), "render_key": frames.config.key()}
    if task == "segmentation":
        segmenter = UNetRunner.load(weights)
        per_class, per_image, _ = evaluate_segmentation(segmenter, (frames.frame(i) for i in range(n_frames)),
                                                        keep=0)
        means = per_class.groupby("class")[["precision", "recall", "iou"]].mean()
        out["per_class"] = {c: {m: float(means.loc[c, m]) for m in means.columns} for c in _SEGMENTATION_CLASSES}
        out["global_accuracy"] = float(per_image["global_accuracy"].mean())
        iou = per_class.pivot(index="image", columns="class", values="iou")
        out["per_frame"] = {c: [float(v) for v in iou[c]] for c in _SEGMENTATION_CLASSES}
    elif task == "orientation":
        source = LearnedOrientation.load(weights)
        results = evaluate_orientation(source, (frames.frame(i) for i in range(n_frames)),
                                       np.random.default_rng(seed))
        table = angle_table(results).set_index("angle")
        direction = direction_error_summary(results)
        out.update(azimuth_mae_deg=float(table.loc["azimuth", "mae_deg"]),
                   elevation_mae_deg=float(table.loc["elevation", "mae_deg"]),
                   direction_median_deg=direction["median_deg"], direction_p90_deg=direction["p90_deg"],
                   misread_fraction=direction["misread_fraction"],
                   per_frame={"direction_error_deg": [float(v) for v in results["direction_error_deg"]]})
    else:
        raise ValueError(f"task must be 'segmentation' or 'orientation', got {task!r}")
    return out


def compare_held_out(task: str, candidate: dict, baseline: dict) -> dict:
    """Two networks' :func:`evaluate_held_out` figures on the same frames, frame by frame.

    Args:
        task: ``"segmentation"`` (each class's IoU, higher is better) or ``"orientation"`` (the
            direction error, lower is better).
        candidate: the campaign network's :func:`evaluate_held_out` result.
        baseline: the baseline's (the shipped network's) on the same seed, frames and renderer.

    Returns:
        Per figure (a class name, or ``direction_error_deg``), the
        :func:`~histostudy.study.stats.paired_comparison` of the candidate against the baseline.

    Raises:
        ValueError: an unknown task, or results of other frames (seed, count or renderer differ) or
            without per-frame figures.
    """
    if task not in ("segmentation", "orientation"):
        raise ValueError(f"task must be 'segmentation' or 'orientation', got {task!r}")
    for key in ("seed", "frames", "render_key"):
        if candidate.get(key) != baseline.get(key):
            raise ValueError(f"candidate and baseline were measured on other frames: {key} "
                             f"{candidate.get(key)!r} and {baseline.get(key)!r}")
    if "per_frame" not in candidate or "per_frame" not in baseline:
        raise ValueError("candidate and baseline must hold per-frame figures (evaluate_held_out's 'per_frame')")

    def values(result, figure):
        return np.array([np.nan if v is None else v for v in result["per_frame"][figure]], dtype=np.float64)

    figures = _SEGMENTATION_CLASSES if task == "segmentation" else ("direction_error_deg",)
    return {figure: paired_comparison(values(candidate, figure), values(baseline, figure),
                                      higher_is_better=task == "segmentation") for figure in figures}
