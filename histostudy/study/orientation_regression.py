"""Notebook 03: the VGG19 azimuth/elevation regression evaluated as in §II-E.2 and §III.

For each evaluation frame the orientation source's angles are compared with the true pose's
(:func:`histostudy.learning.orientation.angles_from_direction`): mean absolute error ± SD (azimuth
differences wrapped), Pearson correlation, and the Moore-Penrose linear fit of prediction on
reference with its R² (:func:`histostudy.study.stats.angle_statistics`).
"""

from __future__ import annotations

import time
from typing import Iterable

import numpy as np
import pandas as pd

from histostudy.learning import (angles_from_direction, beam_direction_of_pose, direction_candidates,
                                 orientation_angle_error, wrap_angle)
from .stats import angle_statistics

__all__ = ["angle_table", "candidate_error_summary", "candidate_errors", "direction_error_summary", "evaluate_orientation",
           "scatter_figure"]


def evaluate_orientation(source, frames: Iterable, rng: np.random.Generator | None = None) -> pd.DataFrame:
    """One row per frame: reference and predicted azimuth and elevation (deg), the wrapped azimuth
    error, the elevation error and the angle between the predicted and the reference direction
    (deg; :func:`~histostudy.learning.orientation.orientation_angle_error`), and the ``seconds`` the source
    took."""
    rows = []
    for i, frame in enumerate(frames):
        if frame.T_carm_transducer is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no true pose to evaluate against")
        ref_az, ref_el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        t0 = time.perf_counter()
        az, el = source.estimate(frame, rng)
        seconds = time.perf_counter() - t0
        rows.append({"image": i, "view": frame.view.name,
                     "azimuth_ref_deg": np.degrees(ref_az), "azimuth_pred_deg": np.degrees(az),
                     "elevation_ref_deg": np.degrees(ref_el), "elevation_pred_deg": np.degrees(el),
                     "azimuth_error_deg": float(np.degrees(wrap_angle(az - ref_az))),
                     "elevation_error_deg": float(np.degrees(el - ref_el)),
                     "direction_error_deg": float(np.degrees(orientation_angle_error(az, el, ref_az, ref_el))),
                     "seconds": seconds})
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.DataFrame(rows)


def angle_table(results: pd.DataFrame) -> pd.DataFrame:
    """The §III statistics per angle: MAE, SD, Pearson r (percent) and p, intercept, slope, R², n."""
    rows = []
    for angle, wrap in (("azimuth", True), ("elevation", False)):
        s = angle_statistics(np.radians(results[f"{angle}_pred_deg"]), np.radians(results[f"{angle}_ref_deg"]), wrap=wrap)
        rows.append({"angle": angle, "mae_deg": s["mae_deg"], "sd_deg": s["sd_deg"],
                     "pearson_percent": 100.0 * s["pearson_r"], "pearson_p": s["pearson_p"],
                     "intercept_deg": s["intercept_deg"], "slope": s["slope"], "r2": s["r2"], "n": s["n"]})
    return pd.DataFrame(rows)


def direction_error_summary(results: pd.DataFrame, misread_deg: float = 30.0) -> dict:
    """The direction error of :func:`evaluate_orientation`'s rows (beyond the paper, which reports
    the two angles only): mean ± SD, median and 90th percentile (deg), and the fraction of frames
    misread by more than ``misread_deg``: the frames whose initialisation must lean on the other
    view (:func:`histostudy.pose.estimate_pose`'s per-view direction starts)."""
    if not (np.isfinite(misread_deg) and misread_deg > 0):
        raise ValueError(f"misread_deg must be finite and > 0, got {misread_deg!r}")
    e = np.asarray(results["direction_error_deg"], dtype=np.float64)
    if e.size == 0:
        raise ValueError("results must hold at least one row")
    return {"mean_deg": float(e.mean()), "sd_deg": float(e.std(ddof=1)) if e.size > 1 else float("nan"),
            "median_deg": float(np.median(e)), "p90_deg": float(np.percentile(e, 90)),
            "misread_fraction": float(np.mean(e > misread_deg)), "misread_deg": float(misread_deg), "n": int(e.size)}


def _source_candidates(source, frame, rng) -> tuple[np.ndarray, bool]:
    own = getattr(source, "candidates", None)
    if own is not None:
        pair, fell_back = own(frame, rng)
        return np.asarray(pair, dtype=np.float64), bool(fell_back)
    return direction_candidates(*source.estimate(frame, rng), frame.view), False


def candidate_errors(sources: dict, frames: Iterable, rng: np.random.Generator | None = None) -> pd.DataFrame:
    """What the pose initialisation starts from, per frame and orientation source (beyond the paper).

    Every source gives each view two candidate world directions of the transducer axis: eq. 4's
    mirror pair of its ``(azimuth, elevation)``, or, for a source with a ``candidates(frame, rng)``
    method (:class:`~histostudy.pose.conic_orientation.ConicOrientation`), its own pair; the pose
    initialisation resolves the pair across views (§II-B.4). One row per frame and source: the
    angle (deg) between the true focal direction and the nearer candidate, that candidate's
    azimuth and elevation errors in the view (the §III angles: the canonical mirror folded, azimuth
    wrapped), whether the source fell back to another (``fell_back``) and its ``seconds``. For an
    ``(azimuth, elevation)`` source the nearer candidate's angle is its direction error of
    :func:`evaluate_orientation`.
    """
    if not isinstance(sources, dict) or not sources:
        raise ValueError(f"sources must be a non-empty dict {{name: orientation source}}, got {sources!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    rows = []
    for i, frame in enumerate(frames):
        if frame.T_carm_transducer is None:
            raise ValueError(f"frame {i} (view {frame.view.name!r}) has no true pose to evaluate against")
        truth = beam_direction_of_pose(frame.T_carm_transducer)
        ref_az, ref_el = angles_from_direction(truth, frame.view)
        for name, source in sources.items():
            t0 = time.perf_counter()
            pair, fell_back = _source_candidates(source, frame, rng)
            seconds = time.perf_counter() - t0
            pair = pair / np.linalg.norm(pair, axis=1, keepdims=True)
            nearest = pair[int(np.argmax(pair @ truth))]
            az, el = angles_from_direction(nearest, frame.view)
            rows.append({"image": i, "view": frame.view.name, "source": name,
                         "candidate_error_deg": float(np.degrees(np.arccos(np.clip(nearest @ truth, -1.0, 1.0)))),
                         "azimuth_error_deg": float(np.degrees(wrap_angle(az - ref_az))),
                         "elevation_error_deg": float(np.degrees(el - ref_el)),
                         "elevation_ref_deg": float(np.degrees(ref_el)),
                         "fell_back": fell_back, "seconds": seconds})
    if not rows:
        raise ValueError("frames must hold at least one frame")
    return pd.DataFrame(rows)


def candidate_error_summary(per_frame: pd.DataFrame, misread_deg: float = 30.0) -> pd.DataFrame:
    """Per source of :func:`candidate_errors`: median, 90th percentile and mean of the nearer
    candidate's angle (deg), the fraction of frames off by more than ``misread_deg``, the azimuth
    and elevation MAE of the nearer candidate (deg), the fraction of frames the source fell back on,
    the median seconds and n."""
    if not (np.isfinite(misread_deg) and misread_deg > 0):
        raise ValueError(f"misread_deg must be finite and > 0, got {misread_deg!r}")
    rows = []
    for name, g in per_frame.groupby("source", sort=False):
        e = g["candidate_error_deg"].to_numpy()
        rows.append({"source": name, "median_deg": float(np.median(e)), "p90_deg": float(np.percentile(e, 90)),
                     "mean_deg": float(e.mean()), "misread_fraction": float(np.mean(e > misread_deg)),
                     "azimuth_mae_deg": float(g["azimuth_error_deg"].abs().mean()),
                     "elevation_mae_deg": float(g["elevation_error_deg"].abs().mean()),
                     "fallback_fraction": float(g["fell_back"].mean()), "seconds_median": float(g["seconds"].median()),
                     "n": int(len(g))})
    return pd.DataFrame(rows)


def scatter_figure(results: pd.DataFrame, table: pd.DataFrame | None = None):
    """Predicted against reference azimuth and elevation with the identity line and the linear fit.

    Azimuth predictions are drawn on the branch nearest the reference (``ref + wrapped error``),
    the branch the statistics use.
    """
    import matplotlib.pyplot as plt

    table = angle_table(results) if table is None else table
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    for ax, angle, lim in zip(axes, ("azimuth", "elevation"), ((-180, 180), (0, 90))):
        ref = results[f"{angle}_ref_deg"].to_numpy()
        pred = ref + results[f"{angle}_error_deg"].to_numpy()
        ax.scatter(ref, pred, s=10, alpha=0.7, label="frames")
        ax.plot(lim, lim, "k--", lw=1, label="identity")
        row = table[table["angle"] == angle].iloc[0]
        x = np.array(lim, dtype=float)
        ax.plot(x, row["intercept_deg"] + row["slope"] * x, "r-", lw=1,
                label=f"fit: {row['slope']:.3f} x {row['intercept_deg']:+.2f}°, R² {row['r2']:.3f}")
        ax.set_xlim(lim)
        ax.set_xlabel(f"reference {angle} (deg)")
        ax.set_ylabel(f"predicted {angle} (deg)")
        ax.set_title(f"{angle}: MAE {row['mae_deg']:.2f} ± {row['sd_deg']:.2f}°")
        ax.legend(loc="upper left", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
    fig.tight_layout()
    return fig
