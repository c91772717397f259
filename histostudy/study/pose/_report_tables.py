"""The tables and comparison rows of notebook 04's report (§III, Table II), shaped from the study's
records and the sweeps' rows: Table II beside the paper, the ``writer.compare`` keyword arguments,
the failures, the focal error per degradation level and per dose. Errors in mm, C-arm frame.
"""

from __future__ import annotations

from collections.abc import Mapping

import pandas as pd

__all__ = ["failed_estimates", "focal_error_per_dose", "focal_error_per_level", "init_success_comparisons",
           "stages_comparison_table", "table2_beside_paper", "table2_both_references", "table2_comparisons"]

#: Table II's rows: label in the paper's table -> key part of :mod:`histostudy.reporting.paper`.
TABLE2_ROWS = {"Center Bias": "center_bias", "Center MAE": "center_mae", "Margin MAE": "margin_mae",
               "Radius MAE": "radius_mae"}
#: Table II's columns: header -> direction key (``overall``: Euclidean or over all directions).
TABLE2_COLUMNS = (("Depth", "depth"), ("TB", "tb"), ("LR", "lr"), ("Overall", "overall"))

#: The columns of every estimate the report tabulates (``pose_records``).
RECORD_COLUMNS = ["experiment", "radius_mm", "position", "mode", "maps", "err_depth", "err_tb", "err_lr",
                  "err_euclidean", "rotation_error_deg", "iterations", "s_total", "ok"]
#: The columns of the CBCT reference the report tabulates (``cbct_reference``).
REFERENCE_TABLE_COLUMNS = ["experiment", "radius_mm", "ref_err_depth", "ref_err_tb", "ref_err_lr",
                           "ref_err_euclidean", "ref_radius_depth", "ref_radius_tb", "ref_radius_lr",
                           "sphere_radius_mm", "clearance_mm", "n_points", "ok", "seconds"]
#: The columns of a failed estimate (``failed_estimates``).
FAILURE_COLUMNS = ["experiment", "position", "mode", "maps", "failure"]


def failed_estimates(records: pd.DataFrame) -> pd.DataFrame:
    """The rows of :func:`run_pose_study` whose estimate failed: experiment, position, mode, maps, failure."""
    return records[~records["ok"].astype(bool)][FAILURE_COLUMNS]


def _paper_cell(paper: Mapping, label: str, direction: str) -> str:
    key = f"table2.{TABLE2_ROWS[label]}.{direction}"
    return paper[key].format() if key in paper else "N/A"


def table2_beside_paper(table: pd.DataFrame, paper: Mapping) -> pd.DataFrame:
    """:func:`table2`'s table with the paper's value after each column (``"<col> (paper)"``, "N/A"
    where the paper gives none). ``paper``: key -> value with ``format()``, as
    :data:`histostudy.reporting.PAPER`."""
    side = table.copy()
    for col, d in TABLE2_COLUMNS:
        side[f"{col} (paper)"] = [_paper_cell(paper, r, d) for r in table[""]]
    return side[["", "Depth", "Depth (paper)", "TB", "TB (paper)", "LR", "LR (paper)", "Overall", "Overall (paper)"]]


def table2_both_references(table_cbct: pd.DataFrame, table_truth: pd.DataFrame, paper: Mapping) -> pd.DataFrame:
    """Table II against both references and the paper in one table: ``"CBCT / truth"`` per cell,
    then the paper's value."""
    both = table_cbct[[""]].copy()
    for col, d in TABLE2_COLUMNS:
        both[f"{col}: CBCT / truth"] = [f"{a} / {b}" if a != "N/A" else "N/A"
                                       for a, b in zip(table_cbct[col], table_truth[col])]
        both[f"{col} (paper)"] = [_paper_cell(paper, r, d) for r in table_cbct[""]]
    return both


def table2_comparisons(values: Mapping, prefix: str, reference_label: str) -> list[dict]:
    """The ``writer.compare`` keyword arguments of Table II's values (:func:`table2`'s ``table2.*``
    keys), recorded under ``prefix`` and set beside the paper's value of the same key."""
    rows = []
    for key, (mean, sd) in values.items():
        if key.startswith("table2."):
            name = key[len("table2."):]
            rows.append(dict(key=prefix + name, label=f"Table II {name.replace('_', ' ')} ({reference_label})",
                             ours=(mean, sd), unit="mm", paper_key=key))
    return rows


def init_success_comparisons(rates: pd.DataFrame) -> list[dict]:
    """The ``writer.compare`` keyword arguments of :func:`robustness_summary`'s rows grouped by
    ``("stages", "init")``: success in percent, with the refusals and wrong acceptances as note."""
    rows = []
    for row in rates.itertuples():
        is_learned = row.stages != "oracle"
        label = {"learned": ", learned stages", "learned-vgg19": ", learned stages, VGG19 orientation"}.get(row.stages,
                                                                                                            "")
        rows.append(dict(key=f"pose.init_success.{row.init}" + (f".{row.stages}" if is_learned else ""),
                         label=f"Initialisation success ({row.init}{label}), {row.poses} random poses",
                         ours=100 * row.success_rate, unit="%", digits=0, paper_key="",
                         note=(f"{row.refused} refused by the verdict, {row.wrong_accepted} accepted off by ≥ 2 mm"
                               + ("" if is_learned else "; target ≥ 99 % (robust)"))))
    return rows


def focal_error_per_level(degrade: pd.DataFrame) -> pd.DataFrame:
    """:func:`degradation_sweep`'s rows per level: poses, mean and max focal error (mm), failures."""
    per_level = degrade.groupby("level").agg(poses=("pose", "size"), mean_error_mm=("error_mm", "mean"),
                                             max_error_mm=("error_mm", "max"), failed=("ok", lambda s: int((~s).sum())))
    return per_level.reset_index()


def focal_error_per_dose(noise: pd.DataFrame) -> pd.DataFrame:
    """:func:`noise_sweep`'s rows per photon count: poses, mean focal error (mm), failures."""
    per_dose = noise.groupby("photons_per_pixel").agg(poses=("pose", "size"), mean_error_mm=("error_mm", "mean"),
                                                      failed=("ok", lambda s: int((~s).sum())))
    return per_dose.reset_index()


def stages_comparison_table(learned: pd.DataFrame, oracle: pd.DataFrame) -> pd.DataFrame:
    """The same frames estimated with the learned stages and with the oracles (:func:`run_pose_study`
    rows): estimates, failures, mean and max focal error (mm), one row per kind of stages."""
    return pd.DataFrame([
        {"stages": "oracle (Table I degradation, paper's angle MAE)", "estimates": len(oracle),
         "failed": int((~oracle["ok"].astype(bool)).sum()), "mean error (mm)": oracle["err_euclidean"].mean(),
         "max error (mm)": oracle["err_euclidean"].max()},
        {"stages": "learned (shipped U-Net, conic / VGG19 orientation)", "estimates": len(learned),
         "failed": int((~learned["ok"].astype(bool)).sum()), "mean error (mm)": learned["err_euclidean"].mean(),
         "max error (mm)": learned["err_euclidean"].max()}])
