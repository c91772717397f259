"""The error budget's figures (§III, §IV): each configuration's Table II and targeting numbers, the
sources' shares of the mean squared error (alone and total), the waterfall and the "lab" row
beside the paper (mm, mm²; docs/error-budget.md, "The design").
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..pose.geometry import DIRECTIONS
from ..pose.metrics import mean_sd
from ._sources import LAB_SOURCES

__all__ = ["STUDY_COLUMNS", "budget_comparisons", "configuration_table", "dominant_sources", "paired_errors",
           "source_shares", "waterfall_figure"]

#: Per study: the prefix of its signed error columns and its radius-error column.
STUDY_COLUMNS = {"pose": ("centre_err_", "radius_err_overall"), "targeting": ("err_", "radius_err_mm")}


def _study(records: pd.DataFrame, study: str) -> pd.DataFrame:
    if study not in STUDY_COLUMNS:
        raise ValueError(f"study must be one of {tuple(STUDY_COLUMNS)}, got {study!r}")
    if not isinstance(records, pd.DataFrame) or "configuration" not in records.columns:
        raise ValueError("records must be run_error_budget()'s DataFrame (a 'configuration' column)")
    return records[records["study"] == study]


def paired_errors(records: pd.DataFrame, study: str) -> tuple[pd.DataFrame, int]:
    """The rows of ``study`` whose experiment has a finite Euclidean error in every configuration,
    and the number of experiments left out (a refused estimate or calibration somewhere)."""
    rows = _study(records, study)
    prefix = STUDY_COLUMNS[study][0]
    col = f"{prefix}euclidean"
    if col not in rows.columns:
        return rows.iloc[0:0], int(rows["experiment"].nunique())
    finite = rows.assign(_ok=np.isfinite(rows[col].astype(float)))
    complete = finite.groupby("experiment")["_ok"].all()
    keep = complete.index[complete]
    return rows[rows["experiment"].isin(keep)], int((~complete).sum())


def configuration_table(records: pd.DataFrame, study: str) -> pd.DataFrame:
    """One row per configuration, in run order: experiments with an error (``n``) and refused,
    the Euclidean error (mean, SD, RMS), the bias and MAE per direction and the radius MAE (mm)."""
    rows = _study(records, study)
    prefix, radius_col = STUDY_COLUMNS[study]
    out = []
    for label in dict.fromkeys(rows["configuration"]):
        g = rows[rows["configuration"] == label]
        eu = g[f"{prefix}euclidean"].astype(float) if f"{prefix}euclidean" in g else pd.Series(dtype=float)
        ok = eu[np.isfinite(eu)]
        mean, sd = mean_sd(ok)
        row = {"configuration": label, "n": int(len(ok)), "refused": int(len(g) - len(ok)),
               "euclidean_mean_mm": mean, "euclidean_sd_mm": sd,
               "euclidean_rms_mm": float(np.sqrt(np.mean(ok ** 2))) if len(ok) else np.nan}
        for d in DIRECTIONS:
            v = g[f"{prefix}{d}"].astype(float) if f"{prefix}{d}" in g else pd.Series(dtype=float)
            v = v[np.isfinite(v)]
            row[f"bias_{d}_mm"] = float(v.mean()) if len(v) else np.nan
            row[f"mae_{d}_mm"] = float(v.abs().mean()) if len(v) else np.nan
        r = g[radius_col].astype(float).abs() if radius_col in g else pd.Series(dtype=float)
        row["radius_mae_mm"] = float(r[np.isfinite(r)].mean()) if np.isfinite(r).any() else np.nan
        out.append(row)
    return pd.DataFrame(out)


def source_shares(records: pd.DataFrame, study: str) -> pd.DataFrame:
    """The sources' shares of the lab's MSE increment (module docstring), one row per source that
    was toggled, plus ``"interactions"`` (the lab's increment less the first-order ones). Columns:
    ``alone_mse_mm2``, ``total_mse_mm2``, ``alone_share``, ``total_share`` (fractions of the
    increment), ``alone_bias_<d>_mm`` (the bias the source adds alone), ``n_experiments`` and
    ``n_left_out``. Empty when no experiment has an error in every configuration."""
    rows, left_out = paired_errors(records, study)
    prefix = STUDY_COLUMNS[study][0]
    if rows.empty:
        return pd.DataFrame()
    by = {label: g.set_index("experiment").sort_index() for label, g in rows.groupby("configuration", sort=False)}

    def mse(label):
        return float(np.mean(by[label][f"{prefix}euclidean"].astype(float) ** 2))

    def bias(label, d):
        return float(by[label][f"{prefix}{d}"].astype(float).mean())

    base, lab = mse("baseline"), mse("lab")
    increment = lab - base
    out = []
    for name in LAB_SOURCES:
        if f"only {name}" not in by:
            continue
        alone = mse(f"only {name}") - base
        total = lab - mse(f"without {name}")
        out.append({"source": name, "alone_mse_mm2": alone, "total_mse_mm2": total,
                    "alone_share": alone / increment if increment else np.nan,
                    "total_share": total / increment if increment else np.nan,
                    **{f"alone_bias_{d}_mm": bias(f"only {name}", d) - bias("baseline", d) for d in DIRECTIONS}})
    first_order = sum(r["alone_mse_mm2"] for r in out)
    out.append({"source": "interactions", "alone_mse_mm2": increment - first_order, "total_mse_mm2": np.nan,
                "alone_share": (increment - first_order) / increment if increment else np.nan, "total_share": np.nan,
                **{f"alone_bias_{d}_mm": np.nan for d in DIRECTIONS}})
    frame = pd.DataFrame(out)
    frame["n_experiments"] = int(rows["experiment"].nunique())
    frame["n_left_out"] = left_out
    frame.attrs.update(baseline_mse_mm2=base, lab_mse_mm2=lab)
    return frame


def dominant_sources(shares: pd.DataFrame) -> dict:
    """The source with the largest first-order MSE increment, and the one adding the largest
    |bias| along each direction (``{"mse": name, "bias_<d>": name}``); empty for empty shares."""
    sources = shares[shares["source"] != "interactions"] if len(shares) else shares
    if sources.empty:
        return {}
    out = {"mse": str(sources.loc[sources["alone_mse_mm2"].idxmax(), "source"])}
    for d in DIRECTIONS:
        out[f"bias_{d}"] = str(sources.loc[sources[f"alone_bias_{d}_mm"].abs().idxmax(), "source"])
    return out


def waterfall_figure(shares: pd.DataFrame, study: str, title: str = ""):
    """A waterfall of the MSE (mm²): the baseline, each source's first-order increment, the
    interactions, and the lab's total; the RMS (mm) at the ends."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    if shares.empty:
        ax.text(0.5, 0.5, "no experiment with an error in every configuration", ha="center", transform=ax.transAxes)
        ax.set_axis_off()
        return fig
    base, lab = shares.attrs["baseline_mse_mm2"], shares.attrs["lab_mse_mm2"]
    labels = ["baseline", *shares["source"].str.replace("_", " "), "lab"]
    steps = [base, *shares["alone_mse_mm2"], lab]
    level = base
    for i, (_label, step) in enumerate(zip(labels, steps)):
        if i == 0 or i == len(steps) - 1:
            ax.bar(i, step, color="0.45")
            ax.text(i, step, f"RMS {np.sqrt(step):.2f} mm", ha="center", va="bottom", fontsize=8)
            continue
        ax.bar(i, step, bottom=level, color="tab:red" if step >= 0 else "tab:green")
        level += step
    ax.set_xticks(range(len(labels)), labels, rotation=35, ha="right")
    ax.set_ylabel("mean squared error (mm²)")
    ax.set_title(title or f"{study}: where the lab's error comes from (first-order increments)")
    ax.axhline(0, color="k", lw=0.6)
    fig.tight_layout()
    return fig


def budget_comparisons(records: pd.DataFrame, labs: pd.DataFrame | None = None) -> list[dict]:
    """``SectionWriter.compare`` keyword arguments: the "lab" and "baseline" configurations'
    Table II centre error, LR bias and radius MAE, and targeting error and LR bias, each beside
    the paper's value (Table II's keys and §III's targeting keys).

    With ``labs`` (:func:`~._distribution.lab_statistics` of several labs) the "lab" rows are the
    labs' distribution, not one draw: the median over the labs of each lab's mean (and of its SD
    over its experiments), the 5-95 % band of the labs' means and lab 0's own figure in the note.
    Biases as recorded (Table II prediction minus zone, targeting zone minus target)."""
    out = []
    for label in ("lab", "baseline"):
        note = "lab error model, all sources on" if label == "lab" else "every lab source off (the studies as run)"
        for study, keys in _COMPARED:
            if label == "lab" and labs is not None and (labs["study"] == study).any():
                out += _distribution_rows(labs[labs["study"] == study], study, keys)
                continue
            rows = _study(records, study)
            g = rows[rows["configuration"] == label]
            if g.empty:
                continue
            prefix, radius_col = STUDY_COLUMNS[study]
            for key, what, text in keys:
                column = {"euclidean": f"{prefix}euclidean", "bias_lr": f"{prefix}lr", "radius": radius_col}[what]
                values = g[column].astype(float).abs() if what == "radius" else g[column].astype(float)
                values = values[np.isfinite(values)]
                if values.empty:
                    continue
                ours = float(values.mean()) if what == "bias_lr" else mean_sd(values)
                out.append(dict(key=f"budget.{label}.{study}.{key}", label=f"{text} ({label})", ours=ours, unit="mm",
                                paper_key=_paper_key(study, key), note=f"{note}; {len(values)} experiment(s)"))
    return out


#: Per study, the compared figures: (key, what, label).
_COMPARED = (("pose", (("center_mae.overall", "euclidean", "Table II centre error, Euclidean"),
                       ("center_bias.lr", "bias_lr", "Table II centre bias, LR"),
                       ("radius_mae.overall", "radius", "Table II radius MAE"))),
             ("targeting", (("euclidean", "euclidean", "Targeting error, Euclidean"),
                            ("bias.lr", "bias_lr", "Targeting bias, LR"))))


def _paper_key(study: str, key: str) -> str:
    return f"table2.{key}" if study == "pose" else f"targeting.{key}"


def _distribution_rows(stats: pd.DataFrame, study: str, keys) -> list[dict]:
    columns = {"euclidean": ("euclidean_mean_mm", "euclidean_sd_mm"), "bias_lr": ("bias_lr_mm", None),
               "radius": ("radius_mae_mm", None)}
    out = []
    for key, what, text in keys:
        mean_col, sd_col = columns[what]
        if mean_col not in stats:
            continue
        values = stats[mean_col].to_numpy(float)
        finite = values[np.isfinite(values)]
        if finite.size == 0:
            continue
        median = float(np.median(finite))
        sds = stats[sd_col].to_numpy(float) if sd_col in stats else np.array([])
        ours = (median, float(np.median(sds[np.isfinite(sds)]))) if np.isfinite(sds).any() else median
        lo, hi = np.percentile(finite, (5.0, 95.0))
        lab0 = stats.loc[stats["lab"] == 0, mean_col]
        first = f"; lab 0 alone: {float(lab0.iloc[0]):.2f} mm" if len(lab0) and np.isfinite(lab0.iloc[0]) else ""
        out.append(dict(key=f"budget.lab.{study}.{key}", label=f"{text} (lab)", ours=ours, unit="mm",
                        paper_key=_paper_key(study, key),
                        note=f"lab error model, all sources on: median of {finite.size} labs (each lab's mean over its "
                             f"experiments{', ± the median SD' if isinstance(ours, tuple) else ''}); 5-95 % band of "
                             f"the labs {lo:.2f} to {hi:.2f} mm{first}"))
    return out
