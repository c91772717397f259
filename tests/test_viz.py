"""Figures: colours of Fig. 5 and the label figure layout."""

import matplotlib

matplotlib.use("Agg")
import numpy as np

from histostudy.carm import View
from histostudy.frame import Frame
from histostudy.transducer import Feature
from histostudy.viz import FEATURE_COLOURS, label_rgb, plot_frames_with_labels


def test_label_rgb_uses_the_class_colours():
    labels = np.array([[0, 1, 2], [3, 4, 5]], np.uint8)
    rgb = label_rgb(labels)
    assert rgb.shape == (2, 3, 3) and rgb.dtype == np.uint8
    for k in Feature:
        r, c = divmod(int(k), 3)
        assert tuple(rgb[r, c]) == FEATURE_COLOURS[k]


def test_plot_has_three_panels_per_frame():
    view = View.from_gantry(0, 0, shape=(20, 30), pixel_mm=10.0, name="A")
    labels = np.zeros((20, 30), np.uint8)
    labels[5:10, 5:10] = Feature.TRANSDUCER
    frames = [Frame(np.random.default_rng(0).random((20, 30)), view, labels=labels)] * 2
    fig = plot_frames_with_labels(frames)
    assert len([ax for ax in fig.axes if ax.images]) == 6
    fig2 = plot_frames_with_labels(frames, predictions=[labels, labels])
    assert "segmentation" in fig2.axes[2].get_title()


def test_pose_overlay_marks_the_projected_focal_point():
    from histostudy.carm import default_biplane
    from histostudy.transducer import TransducerModel, pose_facing
    from histostudy.viz import plot_pose_overlay

    view = default_biplane()[0]
    model = TransducerModel.build(spacing_mm=2.0)
    T = pose_facing((0.1, 1.0, 0.2), focal_point_mm=(5.0, -3.0, 2.0))
    frames = [Frame(np.zeros(view.shape, np.float32), view)]
    fig = plot_pose_overlay(frames, model, T, rng=np.random.default_rng(0), max_points_per_class=50)
    assert len(fig.axes) == 2
    (cross,) = [line for line in fig.axes[1].lines if line.get_marker() == "+"]
    expected = view.project(T[:3, 3])[0]
    np.testing.assert_allclose(np.r_[cross.get_xdata(), cross.get_ydata()], expected, atol=1e-9)
    # One scatter per feature class with points, each at most max_points_per_class points.
    sizes = [len(c.get_offsets()) for c in fig.axes[1].collections]
    assert len(sizes) == sum(len(p) > 0 for p in model.points.values()) and max(sizes) <= 50
