"""Notebook 02: the U-Net segmentation evaluated as in §II-E.1 and §III (Table I, ANOVA, Tukey HSD).

Every evaluation frame is segmented at full resolution and compared with its reference labels
pixel by pixel (:func:`histostudy.study.stats.segmentation_metrics`); Table I is the mean ± SD over
images of each class's precision, recall, IoU and pixel accuracy (percent). The precision of the
six classes is compared by one-way ANOVA and Tukey's HSD, as the paper does.
"""

from __future__ import annotations

import time
from typing import Iterable

import numpy as np
import pandas as pd

from histostudy.transducer import Feature
from .stats import anova_oneway, segmentation_metrics, tukey_hsd

__all__ = ["CLASS_KEYS", "anova_text", "evaluate_segmentation", "precision_tests", "summary", "table1"]

#: Row names of Table I, in label order (also the paper-value keys ``table1.<class>.<metric>``).
CLASS_KEYS = tuple(f.name.lower() for f in Feature)

METRICS = ("precision", "recall", "iou", "accuracy")


def evaluate_segmentation(segmenter, frames: Iterable, rng: np.random.Generator | None = None, *,
                          keep: int = 3) -> tuple[pd.DataFrame, pd.DataFrame, list]:
    """Segment ``frames`` (any iterable; a generator keeps memory flat) and measure them against
    their reference labels.

    Returns ``(per_class, per_image, predictions)``: ``per_class`` has one row per image and class
    (``image, class, precision, recall, iou, accuracy`` in percent, NaN where undefined, plus the
    confusion counts), ``per_image`` one row per image (``global_accuracy, weighted_iou,
    mean_precision, mean_recall`` in percent, ``seconds`` of segmentation) and ``predictions``
    the label images of the first ``keep`` frames (for figures).
    """
    rows, images, predictions = [], [], []
    for i, frame in enumerate(frames):
        if frame.labels is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no reference labels to evaluate against")
        t0 = time.perf_counter()
        pred = segmenter.segment(frame, rng)
        seconds = time.perf_counter() - t0
        m = segmentation_metrics(pred, frame.labels, len(Feature), class_names=CLASS_KEYS)
        t = m["per_class"].copy()
        t[list(METRICS)] *= 100.0
        t.insert(0, "image", i)
        rows.append(t)
        images.append({"image": i, "global_accuracy": 100.0 * m["global_accuracy"],
                       "weighted_iou": 100.0 * m["weighted_iou"],
                       "mean_precision": float(np.nanmean(t["precision"])),
                       "mean_recall": float(np.nanmean(t["recall"])), "seconds": seconds})
        if i < keep:
            predictions.append(pred)
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.concat(rows, ignore_index=True), pd.DataFrame(images), predictions


def table1(per_class: pd.DataFrame) -> pd.DataFrame:
    """Table I: per class the mean and SD over images (percent) of each metric, and the image count."""
    out = []
    for cls in CLASS_KEYS:
        sub = per_class[per_class["class"] == cls]
        row = {"class": cls}
        for metric in METRICS:
            values = sub[metric].dropna()
            row[f"{metric}_mean"] = float(values.mean()) if len(values) else np.nan
            row[f"{metric}_sd"] = float(values.std(ddof=1)) if len(values) > 1 else np.nan
        row["images"] = int(sub["precision"].notna().sum())
        out.append(row)
    return pd.DataFrame(out)


def summary(per_image: pd.DataFrame) -> pd.DataFrame:
    """Mean and SD over images of the global accuracy, weighted IoU, mean precision and recall."""
    cols = ["global_accuracy", "weighted_iou", "mean_precision", "mean_recall"]
    return pd.DataFrame({"metric": cols, "mean": [per_image[c].mean() for c in cols],
                         "sd": [per_image[c].std(ddof=1) for c in cols]})


def precision_tests(per_class: pd.DataFrame, alpha: float = 0.05) -> tuple[dict, pd.DataFrame, list[str]]:
    """One-way ANOVA and Tukey HSD of the per-image precision over the classes.

    Images where a class's precision is undefined (the class was never predicted) are left out of
    that class's group; a class with fewer than two defined values is left out of the tests and
    named in the returned list. Returns ``(anova, tukey, dropped)``, ``anova`` with ``F,
    df_between, df_within, p``; ``anova`` and ``tukey`` are None when fewer than two classes are
    left (a network that predicts a single class).
    """
    groups, dropped = {}, []
    for cls in CLASS_KEYS:
        values = per_class.loc[per_class["class"] == cls, "precision"].dropna().to_numpy()
        if len(values) >= 2:
            groups[cls] = values
        else:
            dropped.append(cls)
    if len(groups) < 2:
        return None, None, dropped
    F, df_b, df_w, p = anova_oneway(groups)
    return {"F": F, "df_between": df_b, "df_within": df_w, "p": p}, tukey_hsd(groups, alpha), dropped


def anova_text(anova: dict, tukey: pd.DataFrame, reference: str = "background") -> str:
    """The §III paragraph: the ANOVA result and which classes' precision is significantly lower
    than ``reference``'s (with the adjusted p and confidence interval of the difference)."""
    p = anova["p"]
    p_text = "p < 1e-5" if p < 1e-5 else f"p = {p:.3g}"
    text = (f"A one-way ANOVA over the precision of the {anova['df_between'] + 1} classes gives "
            f"F({anova['df_between']}, {anova['df_within']}) = {anova['F']:.1f}, {p_text}. ")
    lower = []
    for row in tukey.itertuples():
        if reference not in (row.group1, row.group2) or not row.reject:
            continue
        other = row.group2 if row.group1 == reference else row.group1
        # meandiff = mean(group2) - mean(group1): express as reference minus other
        diff, lo, hi = ((-row.meandiff, -row.upper, -row.lower) if row.group1 == reference
                        else (row.meandiff, row.lower, row.upper))
        if diff > 0:
            lower.append(f"{other} (by {diff:.1f} %, p_adj = {row.p_adj:.2g}, 95 % CI [{lo:.1f}, {hi:.1f}] %)")
    if lower:
        text += f"Tukey's HSD finds the precision significantly lower than {reference}'s for " + "; ".join(lower) + "."
    else:
        text += f"Tukey's HSD finds no class with a precision significantly lower than {reference}'s."
    return text
