"""Notebook 02's study module: per-image metrics, Table I, the precision tests and their paragraph."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from histostudy.imaging import Frame, View
from histostudy.learning import OracleSegmenter, SegmentationDegradation
from histostudy.study import segmentation as study
from histostudy.transducer import FEATURE_CLASSES


def _frames(n=5, seed=0):
    """Synthetic label images with every class present: nested rectangles and thin stripes."""
    rng = np.random.default_rng(seed)
    view = View.from_gantry(0.0, shape=(48, 64))
    out = []
    for _ in range(n):
        lab = np.zeros((48, 64), np.uint8)
        r, c = rng.integers(2, 6, size=2)
        lab[r:40, c:58] = 1
        lab[r:r + 3, c:58] = 2
        lab[20:23, 10:50] = 3
        lab[r:40, 30:32] = 4
        lab[10:13, 12:15] = 5
        out.append(Frame(rng.normal(size=(48, 64)).astype(np.float32), view, labels=lab))
    return out


def test_perfect_segmentation_scores_100():
    per_class, per_image, preds = study.evaluate_segmentation(OracleSegmenter(), _frames(), keep=2)
    assert len(preds) == 2 and len(per_image) == 5
    assert np.allclose(per_image["global_accuracy"], 100) and np.allclose(per_image["weighted_iou"], 100)
    t = study.table1(per_class)
    assert list(t["class"]) == list(study.CLASS_KEYS)
    assert np.allclose(t[["precision_mean", "recall_mean", "iou_mean", "accuracy_mean"]], 100)
    assert (t["images"] == 5).all()


def test_table1_and_tests_on_a_degraded_oracle_match_scipy():
    deg = SegmentationDegradation(recall={k: 0.7 for k in FEATURE_CLASSES},
                                  precision={k: 0.8 for k in FEATURE_CLASSES})
    frames = _frames(8, seed=1)
    per_class, per_image, _ = study.evaluate_segmentation(OracleSegmenter(deg), frames, np.random.default_rng(2))
    t = study.table1(per_class)
    gaps = per_class.loc[per_class["class"] == "gaps", "recall"]
    row = t[t["class"] == "gaps"].iloc[0]
    assert row["recall_mean"] == pytest.approx(gaps.mean()) and row["recall_sd"] == pytest.approx(gaps.std(ddof=1))
    assert 55 < row["recall_mean"] < 85  # about the requested 70 %
    anova, tukey, dropped = study.precision_tests(per_class)
    groups = [per_class.loc[per_class["class"] == c, "precision"].dropna() for c in study.CLASS_KEYS]
    ref = sps.f_oneway(*groups)
    assert dropped == [] and anova["F"] == pytest.approx(ref.statistic) and anova["p"] == pytest.approx(ref.pvalue)
    assert (anova["df_between"], anova["df_within"]) == (5, 6 * 8 - 6)
    assert len(tukey) == 15
    text = study.anova_text(anova, tukey)
    assert text.startswith(f"A one-way ANOVA over the precision of the 6 classes gives F(5, 42) = {anova['F']:.1f}")
    overall = study.summary(per_image)
    assert overall.loc[overall["metric"] == "global_accuracy", "mean"].iloc[0] == pytest.approx(
        per_image["global_accuracy"].mean())


def test_anova_text_names_the_lower_classes():
    tukey = pd.DataFrame({"group1": ["background", "background"], "group2": ["gaps", "screws"],
                          "meandiff": [-1.0, -8.9], "p_adj": [0.4, 1e-6], "lower": [-3.0, -10.1],
                          "upper": [1.0, -7.7], "reject": [False, True]})
    text = study.anova_text({"F": 85.6, "df_between": 5, "df_within": 1262, "p": 1e-9}, tukey)
    assert "F(5, 1262) = 85.6, p < 1e-5" in text
    assert "screws (by 8.9 %" in text and "[7.7, 10.1]" in text and "gaps" not in text


def test_a_single_predicted_class_gives_no_tests():
    class Background:
        def segment(self, frame, rng=None):
            return np.zeros(frame.shape, np.uint8)

    per_class, _, _ = study.evaluate_segmentation(Background(), _frames(3))
    anova, tukey, dropped = study.precision_tests(per_class)
    assert anova is None and tukey is None and set(dropped) == set(study.CLASS_KEYS) - {"background"}
    with pytest.raises(ValueError, match="no reference labels"):
        study.evaluate_segmentation(Background(), [Frame(np.zeros((48, 64), np.float32), _frames(1)[0].view)])
