"""Table II and the other summaries of notebook 04's pose estimates (§II-E.3, §III; mm, mean ± SD),
from :func:`~histostudy.study.pose.experiments.run_pose_study`'s rows, against the ground truth or
the post-treatment CBCT; errors along the centre pose's depth/TB/LR axes (C-arm frame, mm), times in s.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .geometry import DIRECTIONS, MARGINS
from .reference import reference_by_experiment

__all__ = ["experiment_metrics", "mean_sd", "reference_error_summary", "stage_timing", "table2",
           "tracking_summary", "variant_summary"]


def mean_sd(values) -> tuple[float, float]:
    """Mean and sample SD of the finite ``values``.

    Args:
        values: numbers (non-finite ones are left out).

    Returns:
        ``(mean, sd)``: ``ddof=1``, SD 0 for one value; NaNs without any finite value.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0


def reference_error_summary(reference: pd.DataFrame) -> pd.DataFrame:
    """The error of the CBCT reference against the ground truth (mean ± SD over experiments, mm).

    Args:
        reference: :func:`~histostudy.study.pose.reference.cbct_reference`'s table.

    Returns:
        One row per quantity: centroid minus true bubble-cloud centre along depth/TB/LR and
        Euclidean, zone radius along each direction and fitted sphere radius minus ``r`` (signed:
        negative = the zone reads small).

    Raises:
        TypeError, ValueError: ``reference`` is not ``cbct_reference``'s table.
    """
    reference_by_experiment(reference)  # refuses a table that is not cbct_reference()'s
    def fmt(v):
        return f"{v[0]:+.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
    rows = [{"quantity": f"centroid − true centre, {d}", "mm": fmt(mean_sd(reference[f"ref_err_{d}"]))}
            for d in DIRECTIONS]
    rows.append({"quantity": "centroid − true centre, Euclidean",
                 "mm": fmt(mean_sd(reference["ref_err_euclidean"]))})
    rows += [{"quantity": f"zone radius − r, {d}", "mm": fmt(mean_sd(reference[f"ref_radius_err_{d}"]))}
             for d in DIRECTIONS]
    rows.append({"quantity": "fitted sphere radius − r", "mm": fmt(mean_sd(reference["sphere_radius_err_mm"]))})
    return pd.DataFrame(rows)


def experiment_metrics(records: pd.DataFrame, reference: pd.DataFrame | None = None) -> pd.DataFrame:
    """Per experiment, mode and map kind, the quantities of Table II (mm, §II-E.3).

    Centre error per direction (signed, predicted minus reference, along the centre pose's
    depth/TB/LR axes) and Euclidean; margin error per margin (distance of the predicted margin
    point to the reference surface); predicted radius per direction (half the distance between
    opposite margin predictions) and its absolute error against the reference radius; precision
    (the centroid of the six margin predictions against the centre prediction; needs no reference).
    An experiment run without its margins (``run_pose_study(centre_only=True)``) has the centre's
    columns only.

    Args:
        records: :func:`~histostudy.study.pose.experiments.run_pose_study`'s rows.
        reference: None: the ground truth (the true bubble-cloud centre, the sphere of radius ``r``
            about it); or :func:`~histostudy.study.pose.reference.cbct_reference`'s table (the
            paper's reference: the segmented zone's centroid, its fitted sphere, its radii), with a
            row for every experiment of ``records``.

    Returns:
        One row per (experiment, mode, maps); column ``reference`` says which (``"truth"``, ``"cbct"``).

    Raises:
        ValueError: ``reference`` lacks an experiment of ``records``, or is not ``cbct_reference``'s table.
    """
    refs = None if reference is None else reference_by_experiment(reference)
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
        if all(name in pred for name in MARGINS):
            row.update(_margin_metrics(pred, surface_centre, surface_radius, ref_radius))
        out.append(row)
    return pd.DataFrame(out)


def _margin_metrics(pred: dict, surface_centre: np.ndarray, surface_radius: float, ref_radius: dict) -> dict:
    """An experiment's margin errors, radii and precision from its predicted points (``pred``: position ->
    C-arm mm) against the reference sphere and radii (:func:`experiment_metrics`)."""
    row = {}
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
    return row


def table2(metrics: pd.DataFrame, mode: str, maps: str = "occlusion_aware") -> tuple[pd.DataFrame, dict]:
    """Table II (§III; mean ± SD over experiments, mm) for one mode and map kind.

    Args:
        metrics: :func:`experiment_metrics`' rows, against one reference.
        mode: the refinement mode (``"paper"``, ``"fast"``).
        maps: the distance-map kind.

    Returns:
        ``(table, values)``: the table as the paper prints it, and the values keyed as in
        :mod:`histostudy.reporting.paper` (``table2.<row>.<direction>`` -> (mean, sd)) plus
        ``pose.precision``.

    Raises:
        ValueError: no metrics of that mode and maps, or metrics against both references mixed.
    """
    m = metrics[(metrics["mode"] == mode) & (metrics["maps"] == maps)]
    if m.empty:
        raise ValueError(f"no experiment metrics for mode={mode!r}, maps={maps!r}; have "
                         f"{sorted(set(zip(metrics['mode'], metrics['maps'])))}")
    if "reference" in m and m["reference"].nunique() > 1:
        raise ValueError(f"metrics mix references {sorted(m['reference'].unique())}: compute Table II per reference")
    values = {}
    for d in DIRECTIONS:
        values[f"table2.center_bias.{d}"] = mean_sd(m[f"centre_err_{d}"])
        values[f"table2.center_mae.{d}"] = mean_sd(np.abs(m[f"centre_err_{d}"]))
        values[f"table2.margin_mae.{d}"] = mean_sd(m[f"margin_err_{d}"])
        values[f"table2.radius_mae.{d}"] = mean_sd(m[f"radius_err_{d}"])
    values["table2.center_mae.overall"] = mean_sd(m["centre_err_euclidean"])
    values["table2.margin_mae.overall"] = mean_sd(m[[f"margin_err_{n}" for n in MARGINS]].to_numpy().ravel())
    values["table2.radius_mae.overall"] = mean_sd(m[[f"radius_err_{d}" for d in DIRECTIONS]].to_numpy().ravel())
    values["pose.precision"] = mean_sd(m["precision"])
    def fmt(v):
        return f"{v[0]:.2f} ± {v[1]:.2f}" if np.isfinite(v[0]) else "n/a"
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
    (mean ± SD over experiments, mm): the modes and map kinds side by side.

    Args:
        metrics: :func:`experiment_metrics`' rows.

    Returns:
        One row per (mode, maps), the values as ``"mean ± SD"`` text.
    """
    rows = []
    for (mode, maps), m in metrics.groupby(["mode", "maps"], sort=False):
        row = {"mode": mode, "maps": maps, "experiments": len(m)}
        for label, values in (("centre euclidean", m["centre_err_euclidean"]),
                              *((f"centre |{d}|", np.abs(m[f"centre_err_{d}"])) for d in DIRECTIONS),
                              ("radius MAE", m[[f"radius_err_{d}" for d in DIRECTIONS]].to_numpy().ravel()),
                              ("precision", m["precision"])):
            mean, sd = mean_sd(values)
            row[label] = f"{mean:.2f} ± {sd:.2f}" if np.isfinite(mean) else "n/a"
        rows.append(row)
    return pd.DataFrame(rows)


def stage_timing(records: pd.DataFrame) -> pd.DataFrame:
    """Median seconds per stage of :func:`histostudy.pose.estimate_pose`, per (mode, maps); mode
    ``"track"`` is the warm start from the previous estimate (no initialisation).

    Args:
        records: :func:`~histostudy.study.pose.experiments.run_pose_study`'s rows.

    Returns:
        One row per (mode, maps): the accepted estimates and the median seconds of each stage.
    """
    stages = [c for c in records.columns if c.startswith("s_")]
    ok = records[records["ok"].astype(bool)]
    table = ok.groupby(["mode", "maps"], sort=False)[stages].median()
    table.columns = [c[2:] for c in stages]
    table.insert(0, "estimates", ok.groupby(["mode", "maps"], sort=False).size())
    return table.reset_index()


def tracking_summary(records: pd.DataFrame) -> dict:
    """Warm-started margin estimates (mode ``"track"``) beside the same margins estimated from
    scratch in the fast mode.

    Args:
        records: :func:`~histostudy.study.pose.experiments.run_pose_study`'s rows.

    Returns:
        ``n``, ``failed``, and per kind (``track``, ``scratch``) the focal error (mean, SD; mm) and the
        median refinement and total seconds; empty without tracking rows.
    """
    track = records[records["mode"] == "track"]
    if track.empty:
        return {}
    scratch = records[(records["mode"] == "fast") & (records["position"] != "centre")
                      & (records["maps"] == track["maps"].iloc[0])]
    out: dict[str, int | float | tuple[float, float]] = {"n": int(len(track)),
                                                         "failed": int((~track["ok"].astype(bool)).sum())}
    for name, df in (("track", track), ("scratch", scratch)):
        mean, sd = mean_sd(df["err_euclidean"])
        out[f"{name}_error_mm"] = (mean, sd)
        out[f"{name}_refinement_s"] = float(np.nanmedian(df["s_refinement"])) if len(df) else float("nan")
        out[f"{name}_total_s"] = float(np.nanmedian(df["s_total"])) if len(df) else float("nan")
    return out

