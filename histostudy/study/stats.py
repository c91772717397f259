"""Evaluation metrics and statistics of the learned stages (§II-E.1-2, §III): segmentation metrics per
image and class, one-way ANOVA and Tukey's HSD, the angle statistics (MAE, Pearson, Moore-Penrose
fit), and the paired comparison of two networks on the same frames. A ratio whose denominator is 0
is NaN, left out of means (docs/study-sections.md, "02").
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats as _sps

from histostudy.core import stage

__all__ = [
    "anova_oneway",
    "angle_statistics",
    "confusion_counts",
    "linear_fit",
    "mean_absolute_error",
    "paired_comparison",
    "pearson",
    "segmentation_metrics",
    "tukey_hsd",
]


def _check_labels(pred, ref, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    pred, ref = np.asarray(pred), np.asarray(ref)
    if pred.shape != ref.shape or pred.ndim != 2:
        raise ValueError(f"pred and ref must be label images of one 2-D shape, got {pred.shape} and {ref.shape}")
    for name, arr in (("pred", pred), ("ref", ref)):
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} must hold integer class labels, got dtype {arr.dtype}")
        if arr.size and (arr.min() < 0 or arr.max() >= n_classes):
            raise ValueError(f"{name} holds labels outside [0, {n_classes - 1}]: min {arr.min()}, max {arr.max()}")
    return pred, ref


@stage("statistics")
def confusion_counts(pred, ref, n_classes: int = 6) -> np.ndarray:
    """``(n_classes, 4)`` int64 counts ``[TP, FP, FN, TN]`` of each class against all others."""
    if isinstance(n_classes, bool) or not isinstance(n_classes, (int, np.integer)) or n_classes < 2:
        raise ValueError(f"n_classes must be an integer >= 2, got {n_classes!r}")
    pred, ref = _check_labels(pred, ref, n_classes)
    cm = np.bincount(ref.ravel().astype(np.int64) * n_classes + pred.ravel(), minlength=n_classes ** 2)
    cm = cm.reshape(n_classes, n_classes)  # rows: reference, columns: prediction
    tp = np.diag(cm)
    fp = cm.sum(axis=0) - tp
    fn = cm.sum(axis=1) - tp
    tn = cm.sum() - tp - fp - fn
    return np.stack([tp, fp, fn, tn], axis=1).astype(np.int64)


def _ratio(num, den) -> np.ndarray:
    num, den = np.asarray(num, dtype=np.float64), np.asarray(den, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


@stage("statistics")
def segmentation_metrics(pred, ref, n_classes: int = 6, class_names=None) -> dict:
    """Metrics of one predicted label image against its reference (§II-E.1), each class counted
    against all others: precision ``TP/(TP+FP)``, recall ``TP/(TP+FN)``, IoU ``TP/(TP+FP+FN)``,
    pixel accuracy ``(TP+TN)/N``; the global accuracy and the frequency-weighted IoU (class IoUs
    weighted by the class's share of reference pixels).

    Args:
        pred: the predicted label image, 2-D integers in ``[0, n_classes)``.
        ref: the reference label image, of the same shape.
        n_classes: the number of classes (>= 2).
        class_names: the rows' names; None: ``0 .. n_classes - 1``.

    Returns:
        ``{"per_class": DataFrame, "global_accuracy": float, "weighted_iou": float}``; the
        DataFrame has one row per class: ``class, tp, fp, fn, tn, precision, recall, iou,
        accuracy, frequency`` (ratios as fractions, NaN where undefined).

    Raises:
        ValueError: shapes that differ or are not 2-D, non-integer labels, labels out of range, a
            bad ``n_classes``, or ``class_names`` of another length.
    """
    counts = confusion_counts(pred, ref, n_classes)
    tp, fp, fn, tn = counts.T
    n = counts[0].sum()
    names = list(range(n_classes)) if class_names is None else list(class_names)
    if len(names) != n_classes:
        raise ValueError(f"class_names must name {n_classes} classes, got {len(names)}")
    iou = _ratio(tp, tp + fp + fn)
    freq = (tp + fn) / n if n else np.full(n_classes, np.nan)
    table = pd.DataFrame({
        "class": names, "tp": tp, "fp": fp, "fn": fn, "tn": tn,
        "precision": _ratio(tp, tp + fp), "recall": _ratio(tp, tp + fn), "iou": iou,
        "accuracy": _ratio(tp + tn, np.full(n_classes, n)), "frequency": freq,
    })
    present = freq > 0
    weighted = float(np.sum(freq[present] * np.nan_to_num(iou[present]))) if n else math.nan
    return {"per_class": table, "global_accuracy": float(tp.sum() / n) if n else math.nan, "weighted_iou": weighted}


def _groups(groups) -> dict[str, np.ndarray]:
    if not isinstance(groups, dict) or len(groups) < 2:
        raise ValueError(f"groups must be a dict of at least two named groups, got {type(groups).__name__} "
                         f"with {len(groups) if hasattr(groups, '__len__') else '?'} entries")
    out = {}
    for name, values in groups.items():
        arr = np.asarray(values, dtype=np.float64).ravel()
        if arr.size < 2:
            raise ValueError(f"group {name!r} has {arr.size} value(s); each group needs at least two")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"group {name!r} holds NaN or inf; drop undefined values before the test")
        out[str(name)] = arr
    return out


@stage("statistics")
def anova_oneway(groups) -> tuple[float, int, int, float]:
    """One-way ANOVA (equal variances) of ``{name: 1-D values}``: ``(F, df_between, df_within, p)``.

    Through ``statsmodels.stats.oneway.anova_oneway``; the paper reports ``F(5, 1262) = 85.6`` for
    the precision of the six classes.
    """
    from statsmodels.stats.oneway import anova_oneway as _anova

    g = _groups(groups)
    res = _anova(list(g.values()), use_var="equal")
    df_between, df_within = (int(round(d)) for d in res.df)
    return float(res.statistic), df_between, df_within, float(res.pvalue)


@stage("statistics")
def tukey_hsd(groups, alpha: float = 0.05) -> pd.DataFrame:
    """Tukey's HSD for all pairs of ``{name: 1-D values}`` (statsmodels ``pairwise_tukeyhsd``).

    Returns one row per pair ``group1 < group2`` (in sorted name order): ``meandiff`` =
    mean(group2) - mean(group1), ``p_adj``, the ``1 - alpha`` family-wise confidence interval
    ``lower, upper`` of ``meandiff`` and ``reject`` (the means differ at level ``alpha``).
    """
    from statsmodels.stats.multicomp import pairwise_tukeyhsd

    if not (0.0 < alpha < 1.0):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    g = _groups(groups)
    endog = np.concatenate(list(g.values()))
    labels = np.concatenate([[name] * len(v) for name, v in g.items()])
    res = pairwise_tukeyhsd(endog, labels, alpha=alpha)
    names = list(res.groupsunique)
    pairs = [(names[i], names[j]) for i in range(len(names)) for j in range(i + 1, len(names))]
    return pd.DataFrame({
        "group1": [a for a, _ in pairs], "group2": [b for _, b in pairs],
        "meandiff": np.asarray(res.meandiffs, dtype=np.float64),
        "p_adj": np.asarray(res.pvalues, dtype=np.float64),
        "lower": np.asarray(res.confint)[:, 0], "upper": np.asarray(res.confint)[:, 1],
        "reject": np.asarray(res.reject, dtype=bool),
    })


def _pair(x, y) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.asarray(x, dtype=np.float64).ravel(), np.asarray(y, dtype=np.float64).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same length, got {x.size} and {y.size}")
    if x.size < 3:
        raise ValueError(f"x and y need at least 3 pairs, got {x.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    return x, y


@stage("statistics")
def linear_fit(x, y) -> tuple[float, float, float]:
    """``(intercept, slope, r2)`` of ``y = intercept + slope x`` by the Moore-Penrose pseudo-inverse.

    ``[intercept, slope] = pinv([1 x]) y``; ``R² = 1 - SS_res / SS_tot`` (NaN when y is constant).
    """
    x, y = _pair(x, y)
    A = np.column_stack([np.ones_like(x), x])
    intercept, slope = np.linalg.pinv(A) @ y
    residual = y - (intercept + slope * x)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(residual @ residual) / ss_tot if ss_tot > 0 else math.nan
    return float(intercept), float(slope), r2


@stage("statistics")
def pearson(x, y) -> tuple[float, float]:
    """Pearson's ``r`` and the two-sided p value of ``r = 0`` (t test with ``n - 2`` dof)."""
    x, y = _pair(x, y)
    dx, dy = x - x.mean(), y - y.mean()
    den = math.sqrt(float(dx @ dx) * float(dy @ dy))
    if den == 0:
        raise ValueError("x or y is constant: the correlation is undefined")
    r = float(np.clip((dx @ dy) / den, -1.0, 1.0))
    dof = x.size - 2
    if abs(r) == 1.0:
        return r, 0.0
    t = r * math.sqrt(dof / (1.0 - r * r))
    return r, float(2.0 * _sps.t.sf(abs(t), dof))


@stage("statistics")
def mean_absolute_error(pred, ref, *, wrap: bool = False) -> tuple[float, float]:
    """``(MAE, SD)`` of ``|pred - ref|`` (SD with ``ddof = 1``); ``wrap`` takes differences of angles
    in rad into ``(-pi, pi]`` first (azimuth)."""
    p, r = np.asarray(pred, dtype=np.float64).ravel(), np.asarray(ref, dtype=np.float64).ravel()
    if p.shape != r.shape or p.size < 2:
        raise ValueError(f"pred and ref must be of one length >= 2, got {p.size} and {r.size}")
    d = p - r
    if wrap:
        d = np.mod(d + np.pi, 2 * np.pi) - np.pi
    a = np.abs(d)
    return float(a.mean()), float(a.std(ddof=1))


@stage("statistics")
def angle_statistics(pred_rad, ref_rad, *, wrap: bool = False) -> dict:
    """The §II-E.2 statistics of predicted against reference angles, reported in degrees.

    With ``wrap`` (azimuth) each prediction is first unwrapped to the branch nearest its reference
    (``ref + wrap(pred - ref)``), so a prediction of 179° for -179° counts as an error of 2° in the
    MAE, the correlation and the fit alike. Returns ``mae_deg, sd_deg, pearson_r, pearson_p,
    intercept_deg, slope, r2, n``; the correlation is NaN when the predictions are constant.

    Args:
        pred_rad: the predicted angles, rad.
        ref_rad: the reference angles, rad (at least 3, finite, as many as ``pred_rad``).
        wrap: unwrap each prediction to the branch nearest its reference first (azimuth).

    Returns:
        The statistics as a dict (angles in degrees).

    Raises:
        ValueError: lengths that differ, fewer than 3 pairs, or non-finite values.
    """
    p, r = _pair(pred_rad, ref_rad)
    if wrap:
        p = r + (np.mod(p - r + np.pi, 2 * np.pi) - np.pi)
    p_deg, r_deg = np.degrees(p), np.degrees(r)
    mae, sd = mean_absolute_error(p_deg, r_deg)
    try:
        rho, pval = pearson(r_deg, p_deg)
    except ValueError:  # a constant prediction (or reference): no correlation to report
        rho, pval = math.nan, math.nan
    intercept, slope, r2 = linear_fit(r_deg, p_deg)
    return {"mae_deg": mae, "sd_deg": sd, "pearson_r": rho, "pearson_p": pval, "intercept_deg": intercept,
            "slope": slope, "r2": r2, "n": int(p.size)}


@stage("statistics")
def paired_comparison(candidate, baseline, *, higher_is_better: bool = True) -> dict:
    """Two networks measured on the same frames: the per-frame differences and the Wilcoxon
    signed-rank test of their median being 0 (two-sided; zero differences left out, as Wilcoxon's
    original test).

    A campaign's network is judged against the shipped one this way (docs/campaigns.md): the frames
    are the same, so a per-frame difference removes the frames' own difficulty, which dominates the
    spread of either network's figures over 40 frames.

    Args:
        candidate: the candidate's value per frame (NaN where undefined on that frame).
        baseline: the baseline's value on the same frames, in the same order.
        higher_is_better: whether a larger value is better (IoU: yes; an angle error: no); it sets
            which frames count as wins.

    Returns:
        ``n`` (frames where both are defined), ``mean_difference`` and ``median_difference``
        (candidate - baseline, in the values' unit), ``wins``, ``losses`` and ``ties`` (frames where
        the candidate is better, worse, equal), ``wilcoxon_statistic`` and ``p_value`` (NaN for
        fewer than 2 non-zero differences; 1.0 where every difference is 0).

    Raises:
        ValueError: ``candidate`` and ``baseline`` of different lengths, or empty.
    """
    c = np.asarray(candidate, dtype=np.float64).ravel()
    b = np.asarray(baseline, dtype=np.float64).ravel()
    if c.shape != b.shape or c.size == 0:
        raise ValueError(f"candidate and baseline must be per-frame values of the same frames, got {c.size} "
                         f"and {b.size} values")
    both = np.isfinite(c) & np.isfinite(b)
    d = c[both] - b[both]
    better = d if higher_is_better else -d
    out = {"n": int(d.size), "mean_difference": float(d.mean()) if d.size else math.nan,
           "median_difference": float(np.median(d)) if d.size else math.nan,
           "wins": int(np.sum(better > 0)), "losses": int(np.sum(better < 0)), "ties": int(np.sum(d == 0)),
           "wilcoxon_statistic": math.nan, "p_value": math.nan}
    nonzero = int(np.count_nonzero(d))
    if d.size and nonzero == 0:
        out["p_value"] = 1.0
    elif nonzero >= 2:
        res = _sps.wilcoxon(d, zero_method="wilcox", alternative="two-sided")
        out.update(wilcoxon_statistic=float(res.statistic), p_value=float(res.pvalue))
    return out
