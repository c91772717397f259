"""stats.py against independent references: hand-counted confusion, scipy's f_oneway, tukey_hsd,
pearsonr and linregress."""

import numpy as np
import pytest
from scipy import stats as sps

from histostudy.study.stats import (
    angle_statistics,
    anova_oneway,
    confusion_counts,
    linear_fit,
    mean_absolute_error,
    paired_comparison,
    pearson,
    segmentation_metrics,
    tukey_hsd,
)


def test_confusion_counts_and_metrics_by_hand():
    ref = np.array([[0, 0, 1], [1, 2, 2]])
    pred = np.array([[0, 1, 1], [1, 2, 0]])
    # class 0: ref pixels (0,0),(0,1); pred pixels (0,0),(1,2) -> TP 1, FP 1, FN 1, TN 3
    # class 1: ref (0,2),(1,0); pred (0,1),(0,2),(1,0) -> TP 2, FP 1, FN 0, TN 3
    # class 2: ref (1,1),(1,2); pred (1,1) -> TP 1, FP 0, FN 1, TN 4
    expected = np.array([[1, 1, 1, 3], [2, 1, 0, 3], [1, 0, 1, 4]])
    np.testing.assert_array_equal(confusion_counts(pred, ref, 3), expected)
    m = segmentation_metrics(pred, ref, 3)
    t = m["per_class"]
    np.testing.assert_allclose(t["precision"], [1 / 2, 2 / 3, 1.0])
    np.testing.assert_allclose(t["recall"], [1 / 2, 1.0, 1 / 2])
    np.testing.assert_allclose(t["iou"], [1 / 3, 2 / 3, 1 / 2])
    np.testing.assert_allclose(t["accuracy"], [4 / 6, 5 / 6, 5 / 6])
    assert m["global_accuracy"] == pytest.approx(4 / 6)
    assert m["weighted_iou"] == pytest.approx((2 * 1 / 3 + 2 * 2 / 3 + 2 * 1 / 2) / 6)


def test_absent_class_gives_nan_not_a_score():
    ref = np.zeros((4, 4), np.uint8)
    pred = ref.copy()
    pred[0, 0] = 1
    t = segmentation_metrics(pred, ref, 3)["per_class"]
    assert t.loc[1, "precision"] == 0.0 and np.isnan(t.loc[1, "recall"])
    assert np.isnan(t.loc[2, "precision"]) and np.isnan(t.loc[2, "iou"])


def test_segmentation_metrics_bad_input():
    with pytest.raises(ValueError, match="one 2-D shape"):
        segmentation_metrics(np.zeros((3, 3), int), np.zeros((3, 4), int))
    with pytest.raises(ValueError, match="outside"):
        segmentation_metrics(np.full((3, 3), 7), np.zeros((3, 3), int))
    with pytest.raises(ValueError, match="integer"):
        segmentation_metrics(np.zeros((3, 3)), np.zeros((3, 3), int))


def _groups(seed=3):
    rng = np.random.default_rng(seed)
    return {name: rng.normal(mu, sd, n) for name, mu, sd, n in
            [("background", 92, 3, 40), ("screws", 82, 14, 35), ("gaps", 90, 12, 38), ("inner", 97, 3, 41)]}


def test_anova_matches_scipy_f_oneway():
    g = _groups()
    F, df_b, df_w, p = anova_oneway(g)
    ref = sps.f_oneway(*g.values())
    assert F == pytest.approx(ref.statistic, rel=1e-10)
    assert p == pytest.approx(ref.pvalue, rel=1e-8)
    assert (df_b, df_w) == (3, sum(len(v) for v in g.values()) - 4)


def test_tukey_matches_scipy_tukey_hsd():
    g = _groups()
    table = tukey_hsd(g)
    names = list(g)
    ref = sps.tukey_hsd(*g.values())
    ci = ref.confidence_interval(0.95)
    assert len(table) == 6
    for row in table.itertuples():
        i, j = names.index(row.group1), names.index(row.group2)
        # scipy's statistic[i, j] is mean_i - mean_j; statsmodels' meandiff is mean(group2) - mean(group1)
        assert row.meandiff == pytest.approx(-ref.statistic[i, j], rel=1e-10)
        assert row.p_adj == pytest.approx(ref.pvalue[i, j], abs=2e-3)
        assert row.lower == pytest.approx(-ci.high[i, j], rel=1e-3)
        assert row.upper == pytest.approx(-ci.low[i, j], rel=1e-3)
        assert row.reject == (ref.pvalue[i, j] < 0.05)
    assert table["reject"].any() and not table["reject"].all()


def test_group_tests_reject_too_small_groups():
    with pytest.raises(ValueError, match="'b' has 1 value"):
        anova_oneway({"a": [1.0, 2.0], "b": [3.0]})
    with pytest.raises(ValueError, match="at least two named groups"):
        tukey_hsd({"a": [1.0, 2.0, 3.0]})
    with pytest.raises(ValueError, match="NaN"):
        anova_oneway({"a": [1.0, np.nan], "b": [3.0, 4.0]})


def test_linear_fit_and_pearson_match_scipy():
    rng = np.random.default_rng(1)
    x = rng.uniform(-180, 180, 60)
    y = 1.07 * x - 0.2 + rng.normal(0, 5, 60)
    intercept, slope, r2 = linear_fit(x, y)
    ref = sps.linregress(x, y)
    assert (intercept, slope) == pytest.approx((ref.intercept, ref.slope), rel=1e-10)
    assert r2 == pytest.approx(ref.rvalue ** 2, rel=1e-10)
    r, p = pearson(x, y)
    pr = sps.pearsonr(x, y)
    assert r == pytest.approx(pr.statistic, rel=1e-12)
    small_x, small_y = x[:8], 0.2 * x[:8] + rng.normal(0, 60, 8)
    assert pearson(small_x, small_y)[1] == pytest.approx(sps.pearsonr(small_x, small_y).pvalue, rel=1e-8)


def test_mae_wraps_azimuth_and_angle_statistics():
    ref = np.radians([179.0, -179.0, 10.0, -90.0])
    pred = np.radians([-179.0, 179.5, 12.0, -91.0])
    mae, sd = mean_absolute_error(pred, ref, wrap=True)
    assert np.degrees(mae) == pytest.approx((2 + 1.5 + 2 + 1) / 4)
    assert np.degrees(sd) == pytest.approx(np.std([2, 1.5, 2, 1], ddof=1))
    assert np.degrees(mean_absolute_error(pred, ref)[0]) > 90  # without wrap the error is wrong
    s = angle_statistics(pred, ref, wrap=True)
    assert s["mae_deg"] == pytest.approx(1.625) and s["n"] == 4
    assert s["slope"] == pytest.approx(1.0, abs=0.02) and s["r2"] > 0.999 and s["pearson_r"] > 0.999


def test_paired_comparison_counts_frames_and_gives_the_exact_signed_rank_p():
    baseline = np.array([40.0, 35.0, 50.0, 20.0, 60.0, 45.0, np.nan, 30.0])
    candidate = baseline + np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 9.0, 0.0])
    out = paired_comparison(candidate, baseline)
    # the NaN frame is left out, the tie counts as neither; 6 non-zero differences, all positive:
    # the exact two-sided signed-rank p is 2 / 2**6 (only the all-positive and all-negative signs are as extreme)
    assert (out["n"], out["wins"], out["losses"], out["ties"]) == (7, 6, 0, 1)
    assert out["median_difference"] == 3.0 and out["mean_difference"] == pytest.approx(3.0)
    assert out["p_value"] == pytest.approx(2 / 64) and out["wilcoxon_statistic"] == 0.0
    # an error (lower is better): the same differences are losses
    worse = paired_comparison(candidate, baseline, higher_is_better=False)
    assert (worse["wins"], worse["losses"], worse["p_value"]) == (0, 6, out["p_value"])


def test_paired_comparison_of_equal_or_too_few_frames_and_bad_input():
    same = paired_comparison([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert (same["ties"], same["p_value"]) == (3, 1.0)
    one = paired_comparison([2.0, np.nan], [1.0, 1.0])
    assert one["n"] == 1 and one["wins"] == 1 and np.isnan(one["p_value"])
    with pytest.raises(ValueError, match="same frames, got 2 and 3"):
        paired_comparison([1.0, 2.0], [1.0, 2.0, 3.0])
