"""The oracle segmenter: exact labels, and degradation that reaches the requested recall/precision."""

import numpy as np
import pytest

from histostudy.carm import default_biplane
from histostudy.frame import Frame
from histostudy.render import render_labels
from histostudy.segment import OracleSegmenter, SegmentationDegradation, Segmenter, masks_from_labels
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, pose_facing


@pytest.fixture(scope="module")
def frame():
    view = default_biplane()[0]
    model = TransducerModel.build(spacing_mm=0.25)
    T = pose_facing((0.1, 1.0, 0.2), (3.0, -4.0, 6.0), 0.4)
    labels = render_labels(model, T, view)
    return Frame(np.zeros(view.shape, np.float32), view, labels=labels, T_carm_transducer=T)


def test_perfect_oracle_returns_the_reference(frame):
    seg = OracleSegmenter()
    assert isinstance(seg, Segmenter)
    out = seg.segment(frame, np.random.default_rng(0))
    assert np.array_equal(out, frame.labels) and out is not frame.labels


def _recall_precision(pred, ref, k):
    tp = np.sum((pred == k) & (ref == k))
    return tp / np.sum(ref == k), tp / max(np.sum(pred == k), 1)


def test_degradation_reaches_table1_rates(frame):
    deg = SegmentationDegradation.paper_table1()
    out = OracleSegmenter(deg).segment(frame, np.random.default_rng(1))
    for k in FEATURE_CLASSES:
        recall, precision = _recall_precision(out, frame.labels, k)
        assert recall == pytest.approx(deg.recall[k], abs=0.03), k.name
        # false positives of a higher-priority class may take some of a lower class's pixels
        assert precision == pytest.approx(deg.precision[k], abs=0.05), k.name


def test_lost_thin_feature_pixels_fall_back_to_the_elements(frame):
    deg = SegmentationDegradation(recall={Feature.GAPS: 0.5}, precision={})
    out = OracleSegmenter(deg).segment(frame, np.random.default_rng(2))
    lost = (frame.labels == Feature.GAPS) & (out != Feature.GAPS)
    assert lost.sum() > 0 and np.all(out[lost] == Feature.TRANSDUCER)
    others = frame.labels != Feature.GAPS
    assert np.array_equal(out[others], frame.labels[others])


def test_errors_come_in_blobs_not_salt_and_pepper(frame):
    k = Feature.TRANSDUCER
    def isolated_fraction(sigma):
        deg = SegmentationDegradation(recall={k: 0.9}, precision={}, blob_sigma_px=sigma)
        lost = ((frame.labels == k) & (OracleSegmenter(deg).segment(frame, np.random.default_rng(3)) != k))
        neighbours = sum(np.roll(lost, s, axis=a) for a in (0, 1) for s in (-1, 1))
        return np.mean(neighbours[lost] == 0)
    assert isolated_fraction(3.0) < 0.2 * isolated_fraction(0.0)


def test_degradation_is_seeded(frame):
    seg = OracleSegmenter(SegmentationDegradation.paper_table1())
    a = seg.segment(frame, np.random.default_rng(5))
    assert np.array_equal(a, seg.segment(frame, np.random.default_rng(5)))
    assert not np.array_equal(a, seg.segment(frame, np.random.default_rng(6)))


def test_bad_input(frame):
    with pytest.raises(ValueError, match="recall"):
        SegmentationDegradation(recall={Feature.GAPS: 1.5})
    with pytest.raises(ValueError, match="precision"):
        SegmentationDegradation(precision={Feature.BACKGROUND: 0.9})
    unlabeled = Frame(frame.image, frame.view)
    with pytest.raises(ValueError, match="reference labels"):
        OracleSegmenter().segment(unlabeled, np.random.default_rng(0))
    with pytest.raises(TypeError, match="rng"):
        OracleSegmenter(SegmentationDegradation.paper_table1()).segment(frame, None)
    masks = masks_from_labels(frame.labels)
    assert set(masks) == set(FEATURE_CLASSES) and masks[Feature.SCREWS].dtype == bool
