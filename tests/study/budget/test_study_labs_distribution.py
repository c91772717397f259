"""The many labs' figures from known records: statistics per lab against hand-computed values, the
paper's place among the labs against numpy, the sign readings, the movers and the comparisons."""

import numpy as np
import pandas as pd
import pytest

from histostudy.reporting.paper import PAPER
from histostudy.study.budget._distribution import (
    BAND_PERCENT,
    PAPER_FIGURES,
    READINGS,
    bias_scatter_split,
    lab_statistics,
    labs_vs_paper,
    paper_statistics,
    sign_agreement,
    source_movers,
)
from histostudy.study.budget._labs_section import movers_table
from histostudy.study.budget._summary import budget_comparisons

DIRS = ("depth", "tb", "lr")


def _rows(lab, study, errors, euclidean, radius):
    prefix, radius_col = ("centre_err_", "radius_err_overall") if study == "pose" else ("err_", "radius_err_mm")
    return [{"study": study, "lab": lab, "configuration": "lab", "experiment": i,
             **{f"{prefix}{d}": e[j] for j, d in enumerate(DIRS)}, f"{prefix}euclidean": eu, radius_col: r}
            for i, (e, eu, r) in enumerate(zip(errors, euclidean, radius))]


def test_statistics_per_lab_are_the_hand_computed_ones():
    errors = [(1.0, 0.0, -1.0), (3.0, 2.0, -1.0), (2.0, 1.0, -4.0)]
    records = pd.DataFrame(_rows(0, "pose", errors, [1.0, 2.0, 3.0], [0.5, -0.5, 1.0])
                           + _rows(0, "targeting", errors[:1], [4.0], [0.2])
                           + _rows(1, "pose", errors[:2] + [(np.nan, np.nan, np.nan)], [1.0, 2.0, np.nan],
                                   [0.0, 0.0, 0.0]))
    stats = lab_statistics(records).set_index(["lab", "study"])
    pose = stats.loc[(0, "pose")]
    assert pose["n"] == 3 and pose["refused"] == 0
    assert [pose[f"bias_{d}_mm"] for d in DIRS] == pytest.approx([2.0, 1.0, -2.0])
    assert [pose[f"sd_{d}_mm"] for d in DIRS] == pytest.approx([1.0, 1.0, np.sqrt(3.0)])
    assert [pose[f"mae_{d}_mm"] for d in DIRS] == pytest.approx([2.0, 1.0, 2.0])
    assert (pose["euclidean_mean_mm"], pose["euclidean_sd_mm"]) == pytest.approx((2.0, 1.0))
    assert pose["radius_mae_mm"] == pytest.approx(2.0 / 3.0)
    assert (pose["bias2_mm2"], pose["sd2_mm2"], pose["bias_share"]) == pytest.approx((9.0, 5.0, 9.0 / 14.0))
    one = stats.loc[(0, "targeting")]  # one experiment: a bias, no SD, no share
    assert one["bias_lr_mm"] == -1.0 and np.isnan(one["sd_lr_mm"]) and np.isnan(one["bias_share"])
    refused = stats.loc[(1, "pose")]
    assert refused["n"] == 2 and refused["refused"] == 1 and refused["bias_depth_mm"] == pytest.approx(2.0)


def test_the_papers_figures_are_the_papers():
    paper = paper_statistics().set_index(["study", "metric", "direction"])
    for d in DIRS:
        assert paper.loc[("pose", "bias", d), "paper"] == PAPER[f"pose.center_bias.{d}"].mean
        assert paper.loc[("pose", "sd", d), "paper"] == PAPER[f"table2.center_bias.{d}"].sd
        assert paper.loc[("pose", "mae", d), "paper"] == PAPER[f"pose.center_mae.{d}"].mean
        assert paper.loc[("targeting", "bias", d), "paper"] == PAPER[f"targeting.bias.{d}"].mean
        assert paper.loc[("targeting", "mae", d), "paper"] == PAPER[f"targeting.mae.{d}"].mean
        assert PAPER_FIGURES["targeting"]["mae_sd"][DIRS.index(d)] == PAPER[f"targeting.mae.{d}"].sd
    assert paper.loc[("pose", "euclidean_mean", "overall"), "paper"] == PAPER["table2.center_mae.overall"].mean \
        or paper.loc[("pose", "euclidean_mean", "overall"), "paper"] == PAPER["pose.center_euclidean"].mean
    assert paper.loc[("targeting", "euclidean_sd", "overall"), "paper"] == PAPER["targeting.euclidean"].sd
    # targeting's SD per direction from MAE ± SD and bias (sample SDs, n = 6), by hand for depth
    assert paper.loc[("targeting", "sd", "depth"), "paper"] == pytest.approx(np.sqrt(1.2 * (0.83 ** 2 - 0.31 ** 2)
                                                                                      + 0.65 ** 2))
    assert paper.loc[("targeting", "sd", "depth"), "derived"] and not paper.loc[("pose", "sd", "depth"), "derived"]
    share = (0.01 ** 2 + 0.3 ** 2 + 0.77 ** 2) / (0.01 ** 2 + 0.3 ** 2 + 0.77 ** 2 + 0.81 + 0.36 + 0.36)
    assert paper.loc[("pose", "bias_share", "overall"), "paper"] == pytest.approx(share)


def _stats(n=40, seed=3):
    rng = np.random.default_rng(seed)
    rows = []
    for lab in range(n):
        for study in ("pose", "targeting"):
            row = {"lab": lab, "study": study, "euclidean_mean_mm": rng.normal(1.4, 0.3),
                   "euclidean_sd_mm": rng.uniform(0.2, 0.8), "bias_share": rng.uniform(0, 1)}
            for d in DIRS:
                row.update({f"bias_{d}_mm": rng.normal(0, 0.8), f"sd_{d}_mm": rng.uniform(0.2, 1.0),
                            f"mae_{d}_mm": rng.uniform(0.3, 1.2)})
            row["bias2_mm2"] = sum(row[f"bias_{d}_mm"] ** 2 for d in DIRS)
            row["sd2_mm2"] = sum(row[f"sd_{d}_mm"] ** 2 for d in DIRS)
            rows.append(row)
    return pd.DataFrame(rows)


def test_the_papers_place_among_the_labs_is_numpys():
    stats = _stats()
    table = labs_vs_paper(stats, "both")
    assert set(table["reading"]) == {*READINGS, "any"}
    assert (table["metric"] == "bias").sum() == 2 * 2 * 3  # two studies, two readings, three directions
    for r in table.itertuples():
        values = stats.loc[stats["study"] == r.study, f"{r.metric}_{r.direction}_mm" if r.metric in ("bias", "sd",
                                                                                                     "mae")
                           else {"euclidean_mean": "euclidean_mean_mm", "euclidean_sd": "euclidean_sd_mm",
                                 "bias_share": "bias_share"}[r.metric]].to_numpy(float)
        if r.metric == "bias":
            values = values * READINGS[r.reading][r.study]
        lo, hi = np.percentile(values, BAND_PERCENT)
        assert (r.labs_median, r.labs_p05, r.labs_p95) == pytest.approx((np.median(values), lo, hi))
        expected = 100.0 * (np.sum(values < r.paper) + 0.5 * np.sum(values == r.paper)) / values.size
        assert r.paper_percentile == pytest.approx(expected)
        assert r.inside_band == (lo <= r.paper <= hi) and r.n_labs == 40
    # the two readings mirror the labs' biases: the paper's percentile moves, the band flips
    pose_lr = table[(table["study"] == "pose") & (table["metric"] == "bias") & (table["direction"] == "lr")]
    a, b = pose_lr.set_index("reading").loc[list(READINGS)].itertuples()
    assert a.labs_p05 == pytest.approx(-b.labs_p95) and a.labs_median == pytest.approx(-b.labs_median)
    only = labs_vs_paper(stats, "zone_minus_prediction")
    assert set(only["reading"]) == {"zone_minus_prediction", "any"}
    with pytest.raises(ValueError, match="reading must be one of"):
        labs_vs_paper(stats, "truth_minus_prediction")


def test_bias_scatter_split_and_signs():
    stats = _stats(n=21)
    split = bias_scatter_split(stats).set_index("study")
    assert split.loc["pose", "paper_bias_share"] == pytest.approx(
        split.loc["pose", "paper_bias2_mm2"] / (split.loc["pose", "paper_bias2_mm2"] + split.loc["pose",
                                                                                                 "paper_sd2_mm2"]))
    assert split.loc["targeting", "labs_bias_share"] == pytest.approx(
        np.median(stats.loc[stats["study"] == "targeting", "bias_share"]))
    # signs: a lab set where Table II's LR bias is always negative and targeting's always positive
    stats.loc[stats["study"] == "pose", "bias_lr_mm"] = -np.abs(stats.loc[stats["study"] == "pose", "bias_lr_mm"])
    stats.loc[stats["study"] == "targeting", "bias_lr_mm"] = np.abs(stats.loc[stats["study"] == "targeting",
                                                                              "bias_lr_mm"])
    signs = sign_agreement(stats).set_index(["direction", "reading"])
    as_paper = signs.loc[("lr", "prediction_minus_zone")]  # paper: -0.77 and -1.01; targeting flipped
    assert (as_paper["pose_sign_as_paper"], as_paper["targeting_sign_as_paper"], as_paper["both_as_paper"]) == (1, 1, 1)
    other = signs.loc[("lr", "zone_minus_prediction")]
    assert (other["pose_sign_as_paper"], other["both_as_paper"]) == (0, 0)
    assert as_paper["pose_targeting_correlation"] == pytest.approx(other["pose_targeting_correlation"])


def test_movers_find_the_source_that_drives_a_figure():
    stats = _stats(n=30)
    rng = np.random.default_rng(9)
    magnitudes = pd.DataFrame({"lab": range(30), "bubble_offset": rng.uniform(0, 2, 30),
                               "gantry_sag": rng.uniform(0, 1, 30)})
    pose = stats["study"] == "pose"
    stats.loc[pose, "euclidean_mean_mm"] = 0.5 + 0.3 * magnitudes["bubble_offset"].to_numpy()
    movers = source_movers(stats, magnitudes).set_index(["study", "metric", "source"])
    top = movers.loc[("pose", "euclidean_mean_mm", "bubble_offset")]
    assert top["r"] == pytest.approx(1.0) and top["r2"] == pytest.approx(1.0)
    assert top["slope_per_sd"] == pytest.approx(0.3 * np.std(magnitudes["bubble_offset"], ddof=1))
    assert movers.loc[("pose", "euclidean_mean_mm", "gantry_sag"), "r2"] < 0.5
    best = movers_table(movers.reset_index()).set_index(["study", "metric"])
    assert best.loc[("pose", "euclidean_mean_mm"), "source"] == "bubble_offset"
    assert best.loc[("pose", "euclidean_mean_mm"), "next"] == "gantry_sag"
    few = source_movers(stats[stats["lab"] < 2], magnitudes)
    assert few["r"].isna().all()  # two labs say nothing


def test_comparisons_take_the_labs_distribution():
    stats = _stats(n=20)
    records = pd.DataFrame(_rows(0, "pose", [(0.1, 0.2, 0.3)], [0.5], [0.1]))
    records["configuration"] = "baseline"
    rows = {c["key"]: c for c in budget_comparisons(records, stats)}
    lab = rows["budget.lab.pose.center_mae.overall"]
    pose = stats[stats["study"] == "pose"]
    assert lab["paper_key"] == "table2.center_mae.overall"
    assert lab["ours"] == pytest.approx((np.median(pose["euclidean_mean_mm"]), np.median(pose["euclidean_sd_mm"])))
    lo, hi = np.percentile(pose["euclidean_mean_mm"], (5, 95))
    assert f"{lo:.2f} to {hi:.2f} mm" in lab["note"] and "median of 20 labs" in lab["note"]
    assert rows["budget.lab.targeting.bias.lr"]["ours"] == pytest.approx(
        np.median(stats.loc[stats["study"] == "targeting", "bias_lr_mm"]))
    assert rows["budget.baseline.pose.center_mae.overall"]["ours"][0] == pytest.approx(0.5)
    assert "budget.lab.pose.radius_mae.overall" not in rows  # the stats above carry no radius


def test_a_figure_no_lab_has_is_not_placed():
    stats = _stats(n=5).assign(sd_lr_mm=np.nan)  # one experiment per lab: no SD
    row = labs_vs_paper(stats).set_index(["study", "metric", "direction"]).loc[("pose", "sd", "lr")]
    assert row["n_labs"] == 0 and row["inside_band"] is None and np.isnan(row["paper_percentile"])
