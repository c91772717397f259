"""Tests of histostudy.study.pose._report_tables: Table II beside the paper, the comparison rows and
the small tables of notebook 04's report, on inputs with known values."""

import types

import numpy as np
import pandas as pd
import pytest

from histostudy.study.pose._report_tables import (
    failed_estimates,
    focal_error_per_dose,
    focal_error_per_level,
    init_success_comparisons,
    stages_comparison_table,
    table2_beside_paper,
    table2_both_references,
    table2_comparisons,
)

#: A stand-in for histostudy.reporting.PAPER: two of Table II's cells.
PAPER = {"table2.center_mae.depth": types.SimpleNamespace(format=lambda: "0.40 ± 0.20"),
         "table2.radius_mae.overall": types.SimpleNamespace(format=lambda: "0.30 ± 0.10")}


def table2_like():
    labels = ["Center Bias", "Center MAE", "Margin MAE", "Radius MAE"]
    return pd.DataFrame({"": labels, "Depth": ["a1", "a2", "a3", "a4"], "TB": ["b1", "b2", "b3", "b4"],
                         "LR": ["c1", "c2", "c3", "c4"], "Overall": ["N/A", "d2", "d3", "d4"]})


def test_table2_beside_paper_puts_the_papers_value_after_each_column():
    side = table2_beside_paper(table2_like(), PAPER)
    assert list(side.columns) == ["", "Depth", "Depth (paper)", "TB", "TB (paper)", "LR", "LR (paper)", "Overall",
                                  "Overall (paper)"]
    assert side.loc[1, "Depth (paper)"] == "0.40 ± 0.20" and side.loc[3, "Overall (paper)"] == "0.30 ± 0.10"
    assert side.loc[0, "Depth (paper)"] == "N/A" and side.loc[1, "Depth"] == "a2"


def test_table2_both_references_joins_cbct_and_truth_per_cell():
    cbct, truth = table2_like(), table2_like().replace({"a2": "t2", "d3": "t3"})
    both = table2_both_references(cbct, truth, PAPER)
    assert both.loc[1, "Depth: CBCT / truth"] == "a2 / t2" and both.loc[2, "Overall: CBCT / truth"] == "d3 / t3"
    assert both.loc[0, "Overall: CBCT / truth"] == "N/A"  # no overall bias in either
    assert both.loc[3, "Overall (paper)"] == "0.30 ± 0.10"


def test_table2_comparisons_keep_only_table2_keys_under_the_prefix():
    values = {"table2.center_mae.depth": (0.5, 0.1), "table2.margin_mae.overall": (0.7, 0.2),
              "pose.precision": (0.1, 0.0)}
    rows = table2_comparisons(values, "table2_truth.", "ground-truth reference")
    assert [r["key"] for r in rows] == ["table2_truth.center_mae.depth", "table2_truth.margin_mae.overall"]
    assert rows[0]["paper_key"] == "table2.center_mae.depth" and rows[0]["ours"] == (0.5, 0.1)
    assert rows[1]["label"] == "Table II margin mae.overall (ground-truth reference)" and rows[1]["unit"] == "mm"


def test_init_success_comparisons_name_the_learned_stages_and_count_in_percent():
    rates = pd.DataFrame({"stages": ["oracle", "learned-vgg19"], "init": ["robust", "robust"], "poses": [4, 4],
                          "success_rate": [0.75, 0.5], "refused": [1, 0], "wrong_accepted": [0, 2]})
    oracle, vgg = init_success_comparisons(rates)
    assert oracle["key"] == "pose.init_success.robust" and oracle["ours"] == 75.0
    assert oracle["note"].endswith("; target ≥ 99 % (robust)") and oracle["digits"] == 0
    assert vgg["key"] == "pose.init_success.robust.learned-vgg19" and vgg["ours"] == 50.0
    assert vgg["label"] == "Initialisation success (robust, learned stages, VGG19 orientation), 4 random poses"
    assert vgg["note"] == "0 refused by the verdict, 2 accepted off by ≥ 2 mm"


def test_failed_estimates_and_the_error_tables_count_what_they_say():
    records = pd.DataFrame({"experiment": [0, 0, 1], "position": ["centre", "top", "centre"],
                            "mode": ["paper"] * 3, "maps": ["per_class"] * 3, "ok": [True, False, True],
                            "failure": ["", "implausible", ""], "err_euclidean": [0.2, np.nan, 0.6]})
    failed = failed_estimates(records)
    assert failed.to_dict("records") == [{"experiment": 0, "position": "top", "mode": "paper", "maps": "per_class",
                                          "failure": "implausible"}]
    degrade = pd.DataFrame({"pose": [0, 1, 0, 1], "level": [0.0, 0.0, 1.0, 1.0], "error_mm": [0.1, 0.3, 0.5, np.nan],
                            "ok": [True, True, True, False]})
    per_level = focal_error_per_level(degrade).set_index("level")
    assert per_level.loc[0.0, "mean_error_mm"] == pytest.approx(0.2) and per_level.loc[0.0, "max_error_mm"] == 0.3
    assert per_level.loc[1.0, "failed"] == 1 and per_level.loc[1.0, "poses"] == 2
    noise = degrade.rename(columns={"level": "photons_per_pixel"})
    per_dose = focal_error_per_dose(noise)
    assert list(per_dose.columns) == ["photons_per_pixel", "poses", "mean_error_mm", "failed"]
    assert list(per_dose["failed"]) == [0, 1]
    both = stages_comparison_table(learned=records, oracle=records.iloc[:1])
    assert list(both["estimates"]) == [1, 3] and list(both["failed"]) == [0, 1]
    assert both.loc[1, "mean error (mm)"] == pytest.approx(0.4) and both.loc[0, "max error (mm)"] == 0.2
