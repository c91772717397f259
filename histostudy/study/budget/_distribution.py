"""The labs' figures beside the paper's (§III, Table II): per lab and study the bias, SD and MAE per
direction, the Euclidean error and the bias's share of the squared error, their distribution over
the labs in both sign readings, and which systematic sources move them (mm, mm², fractions;
docs/error-budget.md, "Many labs").
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np
import pandas as pd
from scipy import stats as sps

from ..pose.geometry import DIRECTIONS
from ._summary import STUDY_COLUMNS

__all__ = ["BAND_PERCENT", "MOVER_METRICS", "NATIVE_READING", "PAPER_FIGURES", "READINGS", "bias_scatter_split",
           "lab_statistics",
           "labs_vs_paper", "paper_statistics", "sign_agreement", "source_movers"]

#: The labs' band: these percentiles of their values.
BAND_PERCENT = (5.0, 95.0)

#: How the code signs each study's errors (module docstring).
NATIVE_READING = {"pose": "prediction minus zone", "targeting": "zone minus prediction (target)"}

#: Per reading, the factor that turns each study's recorded bias into it.
READINGS = {"prediction_minus_zone": {"pose": 1.0, "targeting": -1.0},
            "zone_minus_prediction": {"pose": -1.0, "targeting": 1.0}}


class _PaperFigures(TypedDict):
    n: int
    bias: tuple[float, float, float]
    mae: tuple[float, float, float]
    mae_sd: tuple[float, float, float]
    sd: tuple[float, float, float] | None
    euclidean: tuple[float, float]


#: The paper's figures per study (§III text and Table II; mm): experiments, bias, MAE ± SD per
#: direction (depth, TB, LR), Euclidean mean ± SD; Table II's SD of the signed error per direction.
PAPER_FIGURES: dict[str, _PaperFigures] = {
    "pose": {"n": 10, "bias": (0.01, 0.30, -0.77), "mae": (0.69, 0.52, 0.81), "mae_sd": (0.58, 0.40, 0.56),
             "sd": (0.9, 0.6, 0.6), "euclidean": (1.38, 0.54)},
    "targeting": {"n": 6, "bias": (-0.31, 0.11, -1.01), "mae": (0.83, 0.46, 1.05), "mae_sd": (0.65, 0.29, 0.58),
                  "sd": None, "euclidean": (1.64, 0.34)},
}


def _paper_sd(study: str) -> tuple[tuple[float, ...], bool]:
    p = PAPER_FIGURES[study]
    if p["sd"] is not None:
        return tuple(p["sd"]), False
    n = p["n"]
    return tuple(float(np.sqrt(max(n / (n - 1) * (m * m - b * b) + s * s, 0.0)))
                 for m, s, b in zip(p["mae"], p["mae_sd"], p["bias"])), True


def paper_statistics() -> pd.DataFrame:
    """The paper's figures in :func:`lab_statistics`'s terms: one row per (study, metric,
    direction) with ``paper`` (mm, mm² or a fraction) and ``derived`` (not printed in the paper)."""
    rows = []
    for study, p in PAPER_FIGURES.items():
        sd, derived = _paper_sd(study)
        for i, d in enumerate(DIRECTIONS):
            rows += [(study, "bias", d, p["bias"][i], False), (study, "sd", d, sd[i], derived),
                     (study, "mae", d, p["mae"][i], False)]
        rows += [(study, "euclidean_mean", "overall", p["euclidean"][0], False),
                 (study, "euclidean_sd", "overall", p["euclidean"][1], False)]
        bias2, sd2 = float(np.sum(np.square(p["bias"]))), float(np.sum(np.square(sd)))
        rows += [(study, "bias_share", "overall", bias2 / (bias2 + sd2), True)]
    return pd.DataFrame(rows, columns=["study", "metric", "direction", "paper", "derived"])


def lab_statistics(records: pd.DataFrame) -> pd.DataFrame:
    """One row per (lab, study) of ``records`` (:func:`~._labs.run_labs` or
    :func:`~._labs.labs_records`): ``n`` experiments with an error (and ``refused``), per direction
    ``bias_<d>_mm`` (mean signed error, as recorded: module docstring), ``sd_<d>_mm`` (sample SD;
    NaN for one experiment) and ``mae_<d>_mm``; ``euclidean_mean_mm`` / ``euclidean_sd_mm``;
    ``radius_mae_mm``; ``bias2_mm2`` and ``sd2_mm2`` (sums over the directions) and
    ``bias_share``."""
    if not isinstance(records, pd.DataFrame) or not {"lab", "study", "experiment"} <= set(records.columns):
        raise ValueError("records must have the columns lab, study and experiment (run_labs)")
    out = []
    for (lab, study), g in records.groupby(["lab", "study"], sort=True):
        prefix, radius_col = STUDY_COLUMNS[study]
        eu = g[f"{prefix}euclidean"].astype(float) if f"{prefix}euclidean" in g else pd.Series(np.nan, index=g.index)
        ok = g[np.isfinite(eu)]
        row = {"lab": int(lab), "study": study, "n": int(len(ok)), "refused": int(len(g) - len(ok))}
        errors = ok.reindex(columns=[f"{prefix}{d}" for d in DIRECTIONS]).to_numpy(float).reshape(-1, len(DIRECTIONS))
        n = len(errors)
        bias = errors.mean(axis=0) if n else np.full(3, np.nan)
        sd = errors.std(axis=0, ddof=1) if n > 1 else np.full(3, np.nan)
        for i, d in enumerate(DIRECTIONS):
            row[f"bias_{d}_mm"] = float(bias[i])
            row[f"sd_{d}_mm"] = float(sd[i])
            row[f"mae_{d}_mm"] = float(np.abs(errors[:, i]).mean()) if n else np.nan
        e = eu[np.isfinite(eu)].to_numpy(float)
        row["euclidean_mean_mm"] = float(e.mean()) if n else np.nan
        row["euclidean_sd_mm"] = float(e.std(ddof=1)) if n > 1 else np.nan
        r = ok[radius_col].astype(float).abs() if radius_col in ok else pd.Series(dtype=float)
        row["radius_mae_mm"] = float(r.mean()) if len(r) else np.nan
        row["bias2_mm2"] = float(np.sum(bias ** 2))
        row["sd2_mm2"] = float(np.sum(sd ** 2))
        row["bias_share"] = row["bias2_mm2"] / (row["bias2_mm2"] + row["sd2_mm2"])
        out.append(row)
    return pd.DataFrame(out)


def _column(metric: str, direction: str) -> str:
    if metric in ("bias", "sd", "mae"):
        return f"{metric}_{direction}_mm"
    return {"euclidean_mean": "euclidean_mean_mm", "euclidean_sd": "euclidean_sd_mm",
            "bias_share": "bias_share"}[metric]


def _placed(values: np.ndarray, paper: float) -> dict:
    values = values[np.isfinite(values)]
    if values.size == 0:
        return dict(n_labs=0, labs_median=np.nan, labs_p05=np.nan, labs_p95=np.nan, paper_percentile=np.nan,
                    inside_band=None)
    lo, hi = np.percentile(values, BAND_PERCENT)
    return dict(n_labs=int(values.size), labs_median=float(np.median(values)), labs_p05=float(lo),
                labs_p95=float(hi), paper_percentile=float(sps.percentileofscore(values, paper, kind="mean")),
                inside_band=bool(lo <= paper <= hi))


def labs_vs_paper(stats: pd.DataFrame, reading: str = "both") -> pd.DataFrame:
    """Per (study, metric, direction): the paper's value (:func:`paper_statistics`), the labs'
    median and 5-95 % band (:data:`BAND_PERCENT`, linear interpolation), the paper's percentile
    among the labs (``scipy.stats.percentileofscore``, ``kind="mean"``), whether it lies inside
    the band (None where no lab has a value: an SD over one experiment), and ``n_labs`` with a
    value.

    ``reading``: ``"prediction_minus_zone"`` or ``"zone_minus_prediction"`` (:data:`READINGS`):
    the labs' biases in that reading; ``"both"``: a bias row per reading. Column ``reading``
    names it ("any" for the metrics without a sign)."""
    readings = list(READINGS) if reading == "both" else [reading]
    if any(r not in READINGS for r in readings):
        raise ValueError(f"reading must be one of {(*READINGS, 'both')}, got {reading!r}")
    rows = []
    for _, p in paper_statistics().iterrows():
        labs = stats[stats["study"] == p["study"]]
        values = labs[_column(p["metric"], p["direction"])].to_numpy(float)
        for r in (readings if p["metric"] == "bias" else ["any"]):
            signed = values * READINGS[r][p["study"]] if p["metric"] == "bias" else values
            rows.append({"study": p["study"], "metric": p["metric"], "direction": p["direction"], "reading": r,
                         "paper": float(p["paper"]), "derived": bool(p["derived"]), **_placed(signed, p["paper"])})
    return pd.DataFrame(rows)


def bias_scatter_split(stats: pd.DataFrame) -> pd.DataFrame:
    """Per study: the paper's sum of squared biases, of squared SDs and the bias share, beside the
    labs' medians of each and the 5-95 % band of their bias share."""
    paper = paper_statistics().set_index(["study", "metric", "direction"])["paper"]
    rows = []
    for study in PAPER_FIGURES:
        labs = stats[stats["study"] == study]
        p_bias2 = float(sum(paper[(study, "bias", d)] ** 2 for d in DIRECTIONS))
        p_sd2 = float(sum(paper[(study, "sd", d)] ** 2 for d in DIRECTIONS))
        share = _placed(labs["bias_share"].to_numpy(float), p_bias2 / (p_bias2 + p_sd2))
        rows.append({"study": study, "paper_bias2_mm2": p_bias2, "paper_sd2_mm2": p_sd2,
                     "paper_bias_share": p_bias2 / (p_bias2 + p_sd2),
                     "labs_bias2_mm2": float(np.nanmedian(labs["bias2_mm2"])) if len(labs) else np.nan,
                     "labs_sd2_mm2": float(np.nanmedian(labs["sd2_mm2"])) if labs["sd2_mm2"].notna().any() else np.nan,
                     "labs_bias_share": share["labs_median"], "labs_bias_share_p05": share["labs_p05"],
                     "labs_bias_share_p95": share["labs_p95"], "n_labs": share["n_labs"]})
    return pd.DataFrame(rows)


def sign_agreement(stats: pd.DataFrame) -> pd.DataFrame:
    """Per direction and reading: the fraction of labs whose Table II bias has the paper's sign,
    whose targeting bias has it, and both; and the correlation over the labs of the two studies'
    biases in that reading (the same in both readings, which treat the studies alike)."""
    wide = stats.pivot(index="lab", columns="study")
    rows = []
    for d in DIRECTIONS:
        col = f"bias_{d}_mm"
        if ("pose", "targeting") != tuple(s for s in ("pose", "targeting") if (col, s) in wide.columns):
            continue
        both = wide[[(col, "pose"), (col, "targeting")]].dropna()
        for r, sign in READINGS.items():
            pose, targeting = both[(col, "pose")] * sign["pose"], both[(col, "targeting")] * sign["targeting"]
            p_pose, p_targ = (PAPER_FIGURES[s]["bias"][DIRECTIONS.index(d)] for s in ("pose", "targeting"))
            same_pose, same_targ = np.sign(pose) == np.sign(p_pose), np.sign(targeting) == np.sign(p_targ)
            corr = float(np.corrcoef(pose, targeting)[0, 1]) if len(both) > 2 else np.nan
            rows.append({"direction": d, "reading": r, "n_labs": int(len(both)),
                         "pose_sign_as_paper": float(same_pose.mean()) if len(both) else np.nan,
                         "targeting_sign_as_paper": float(same_targ.mean()) if len(both) else np.nan,
                         "both_as_paper": float((same_pose & same_targ).mean()) if len(both) else np.nan,
                         "pose_targeting_correlation": corr})
    return pd.DataFrame(rows)


#: The metrics :func:`source_movers` relates to the sources' draws (|bias| for the biases).
MOVER_METRICS = ("euclidean_mean_mm", *(f"abs_bias_{d}_mm" for d in DIRECTIONS), *(f"sd_{d}_mm" for d in DIRECTIONS),
                 "bias_share")


def source_movers(stats: pd.DataFrame, magnitudes: pd.DataFrame) -> pd.DataFrame:
    """Which systematic source moves each metric across the labs: per (study, metric, source) the
    Pearson correlation ``r`` over the labs between the metric (:data:`MOVER_METRICS`; the
    absolute bias for the biases) and the source's drawn magnitude
    (:func:`~._labs.lab_magnitudes`), ``r²``, and ``slope_per_sd`` (the metric's change per SD of
    the magnitude over the labs: ``r`` times the metric's SD; mm, or a fraction for the bias
    share). A univariate regression on the standardised magnitude: the sources are drawn
    independently, so each slope is unbiased, and ``r²`` is the share of the labs' variance of
    the metric that the source's size explains. NaN with fewer than three labs or a constant."""
    sources = [c for c in magnitudes.columns if c != "lab"]
    merged = stats.merge(magnitudes, on="lab", how="inner")
    for d in DIRECTIONS:
        merged[f"abs_bias_{d}_mm"] = merged[f"bias_{d}_mm"].abs()
    rows = []
    for study, g in merged.groupby("study", sort=False):
        for metric in MOVER_METRICS:
            for source in sources:
                pair = g[[metric, source]].astype(float).dropna()
                y, x = pair[metric].to_numpy(), pair[source].to_numpy()
                ok = len(pair) >= 3 and np.std(x) > 0 and np.std(y) > 0
                r = float(np.corrcoef(x, y)[0, 1]) if ok else np.nan
                rows.append({"study": study, "metric": metric, "source": source, "n_labs": int(len(pair)), "r": r,
                             "r2": r * r if ok else np.nan, "slope_per_sd": r * float(np.std(y, ddof=1)) if ok
                             else np.nan})
    return pd.DataFrame(rows)
