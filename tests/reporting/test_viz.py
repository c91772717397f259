"""Figures: colours of Fig. 5, the label figure layout, the pose overlay and the 3-D targeting scene."""

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest

from histostudy.imaging import Frame, View
from histostudy.reporting import plot_frames_with_labels
from histostudy.reporting.viz import FEATURE_COLOURS, label_rgb
from histostudy.transducer import Feature


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
    from histostudy.imaging import default_biplane
    from histostudy.reporting import plot_pose_overlay
    from histostudy.transducer import TransducerModel, pose_facing

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


# --- the 3-D targeting scene (pyvista, off-screen) --------------------------------------------


def _scene_inputs():
    from histostudy.geometry import make_transform
    from histostudy.imaging import default_biplane
    from histostudy.robot import HOME_JOINTS_RAD
    from histostudy.transducer import TransducerModel, pose_facing

    T_carm_base = make_transform(np.column_stack([[-1.0, 0, 0], [0, 0, -1.0], [0, -1.0, 0]]), [-600.0, 200.0, 0.0])
    return dict(views=default_biplane(), T_carm_base=T_carm_base, joints_rad=np.array(HOME_JOINTS_RAD),
                model=TransducerModel.build(spacing_mm=3.0), T_carm_transducer=pose_facing((0.0, 1.0, 0.0)),
                T_carm_phantom=np.eye(4), target_mm=(1.0, 2.0, 3.0), zone_centre_mm=(1.0, 2.0, 3.0),
                zone_radius_mm=10.0)


def test_detector_corners_lie_on_the_detector_at_the_image_corners():
    from histostudy.imaging import default_biplane
    from histostudy.reporting._targeting_parts import _detector_corners

    for view in default_biplane():
        corners = _detector_corners(view)
        rows, cols = view.shape
        expected = [[-0.5, -0.5], [cols - 0.5, -0.5], [cols - 0.5, rows - 0.5], [-0.5, rows - 0.5]]
        np.testing.assert_allclose(view.project(corners), expected, atol=1e-6)
        # The detector plane is the source-detector distance (1200 mm) from the source along the beam.
        np.testing.assert_allclose((corners - view.source_mm) @ view.principal_direction, 1200.0, atol=1e-6)


def test_targeting_scene_renders_every_part():
    pytest.importorskip("pyvista")
    from histostudy.reporting import targeting_scene

    kw = _scene_inputs()
    full = targeting_scene(rng=np.random.default_rng(0), window_size=(160, 120), close_up=False, **kw)
    assert full.shape == (120, 160, 3) and full.dtype == np.uint8
    assert len(np.unique(full.reshape(-1, 3), axis=0)) > 20  # not a blank or uniform image
    # The same scene without the robot is a different picture.
    no_robot = dict(kw, T_carm_base=None, joints_rad=None)
    without = targeting_scene(rng=np.random.default_rng(0), window_size=(160, 120), close_up=False, **no_robot)
    assert without.shape == full.shape and np.mean(np.any(without != full, axis=2)) > 0.01
    # The close-up panel (right half) shows something other than the overview (left half).
    split = targeting_scene(rng=np.random.default_rng(0), window_size=(240, 120), **kw)
    assert split.shape == (120, 240, 3)
    left, right = split[:, :120], split[:, 120:]
    assert len(np.unique(right.reshape(-1, 3), axis=0)) > 20 and np.any(left != right)


@pytest.mark.parametrize("change, match", [
    (dict(T_carm_base=np.eye(3)), "T_carm_base"),
    (dict(T_carm_transducer=np.diag([2.0, 1.0, 1.0, 1.0])), "T_carm_transducer"),
    (dict(T_carm_phantom=np.full((4, 4), np.nan)), "T_carm_phantom"),
    (dict(joints_rad=np.zeros(5)), "joints_rad"),
    (dict(joints_rad=None), "joints_rad"),
    (dict(zone_radius_mm=-1.0), "zone_radius_mm"),
    (dict(target_mm=(0.0, 1.0)), "target_mm"),
    (dict(views=[]), "views"),
    (dict(rng=None), "rng"),
])
def test_targeting_scene_rejects_bad_input(change, match):
    from histostudy.reporting import targeting_scene

    kw = dict(_scene_inputs(), rng=np.random.default_rng(0), window_size=(64, 48))
    kw.update(change)
    with pytest.raises(ValueError, match=match):
        targeting_scene(**kw)
