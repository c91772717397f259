"""The budget's figures from known records: configuration tables, shares, comparisons."""

import numpy as np
import pandas as pd
import pytest

from histostudy.study.budget._sources import LAB_SOURCES
from histostudy.study.budget._summary import (
    budget_comparisons,
    configuration_table,
    dominant_sources,
    paired_errors,
    source_shares,
    waterfall_figure,
)


def _records(n: int = 40, seed: int = 0) -> pd.DataFrame:
    """Pose records where two sources add independent errors to a baseline: "bubble_offset" a
    constant LR bias of 0.8 mm, "annotation" N(0, 0.4²) per axis; "robot" adds nothing."""
    rng = np.random.default_rng(seed)
    base = rng.normal(0, 0.2, (n, 3))
    bias = np.array([0.0, 0.0, 0.8])
    noise = rng.normal(0, 0.4, (n, 3))
    errors = {"baseline": base, "lab": base + bias + noise,
              "only bubble_offset": base + bias, "only annotation": base + noise, "only robot": base,
              "without bubble_offset": base + noise, "without annotation": base + bias,
              "without robot": base + bias + noise}
    rows = []
    for label, e in errors.items():
        for i, (d, tb, lr) in enumerate(e):
            rows.append({"study": "pose", "configuration": label, "experiment": i, "centre_err_depth": d,
                         "centre_err_tb": tb, "centre_err_lr": lr, "centre_err_euclidean": float(np.linalg.norm([d, tb,
                                                                                                                 lr])),
                         "radius_err_overall": 0.1})
    return pd.DataFrame(rows), errors


def test_shares_of_independent_sources_add_up():
    records, errors = _records(n=400)
    shares = source_shares(records, "pose").set_index("source")
    mse = {k: float(np.mean(np.sum(v ** 2, axis=1))) for k, v in errors.items()}
    assert shares.attrs["baseline_mse_mm2"] == pytest.approx(mse["baseline"])
    assert shares.loc["bubble_offset", "alone_mse_mm2"] == pytest.approx(mse["only bubble_offset"] - mse["baseline"])
    assert shares.loc["annotation", "total_mse_mm2"] == pytest.approx(mse["lab"] - mse["without annotation"])
    assert shares.loc["robot", "alone_share"] == pytest.approx(0.0, abs=1e-12)
    first_order = shares.loc[["bubble_offset", "annotation", "robot"], "alone_share"].sum()
    assert first_order + shares.loc["interactions", "alone_share"] == pytest.approx(1.0)
    assert abs(shares.loc["interactions", "alone_share"]) < 0.1  # independent sources barely interact
    assert shares.loc["bubble_offset", "alone_bias_lr_mm"] == pytest.approx(0.8)
    assert dominant_sources(shares.reset_index())["bias_lr"] == "bubble_offset"
    assert set(shares.index) <= {*LAB_SOURCES, "interactions"}


def test_configuration_table_and_left_out_experiments():
    records, errors = _records(n=10)
    records.loc[(records["configuration"] == "only annotation") & (records["experiment"] == 3),
                "centre_err_euclidean"] = np.nan
    table = configuration_table(records, "pose").set_index("configuration")
    assert table.loc["only annotation", "n"] == 9 and table.loc["only annotation", "refused"] == 1
    assert table.loc["only bubble_offset", "bias_lr_mm"] == pytest.approx(np.mean(errors["only bubble_offset"][:, 2]))
    rows, left_out = paired_errors(records, "pose")
    assert left_out == 1 and 3 not in set(rows["experiment"])
    assert source_shares(records, "pose")["n_experiments"].iloc[0] == 9
    with pytest.raises(ValueError, match="study must be one of"):
        configuration_table(records, "calibration")


def test_comparisons_set_the_lab_beside_the_papers_keys():
    records, _ = _records(n=5)
    rows = {c["key"]: c for c in budget_comparisons(records)}
    lab = rows["budget.lab.pose.center_mae.overall"]
    assert lab["paper_key"] == "table2.center_mae.overall"
    assert lab["ours"][0] == pytest.approx(records.query("configuration == 'lab'")["centre_err_euclidean"].mean())
    assert rows["budget.baseline.pose.center_bias.lr"]["paper_key"] == "table2.center_bias.lr"
    assert not any(k.startswith("budget.lab.targeting") for k in rows)  # no targeting rows in these records


def test_waterfall_draws_every_source():
    records, _ = _records(n=5)
    fig = waterfall_figure(source_shares(records, "pose"), "pose")
    labels = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert labels[0] == "baseline" and labels[-1] == "lab" and "bubble offset" in labels
    empty = waterfall_figure(pd.DataFrame(), "pose")
    assert empty.axes[0].texts
