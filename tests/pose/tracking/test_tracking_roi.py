"""Tests of histostudy.pose.tracking._roi: the tracking region and the view of its pixels.

The cropped view is checked by projecting points: a point's pixel in the region's view must be its
pixel in the full view, shifted by the box's corner and rescaled with View.scaled's pixel-centre
convention (u' = s (u - u0) + (s - 1) / 2).
"""

import numpy as np
import pytest
from pose_frames import POSES

from histostudy.imaging import default_biplane
from histostudy.pose.tracking._roi import RegionOfInterest, crop_view, region_of_interest
from histostudy.transducer import TransducerModel


@pytest.fixture(scope="module")
def view():
    return default_biplane()[0]


@pytest.fixture(scope="module")
def points():
    model = TransducerModel.build(spacing_mm=0.47)
    return np.vstack([p for p in model.points.values()])


@pytest.mark.parametrize("scale", [1.0, 0.5, 0.25])
def test_the_region_view_projects_as_the_full_view_shifted_and_scaled(view, scale):
    box = (96, 704, 160, 992)
    region = crop_view(view, box, scale)
    assert region.shape == ((704 - 96) * scale, (992 - 160) * scale)
    assert region.pixel_mm == pytest.approx(view.pixel_mm / scale) and region.name == view.name
    world = np.random.default_rng(0).uniform(-80.0, 80.0, size=(500, 3))
    u, v = view.project(world).T
    expected = np.column_stack([scale * (u - 160) + (scale - 1) / 2, scale * (v - 96) + (scale - 1) / 2])
    np.testing.assert_allclose(region.project(world), expected, atol=1e-9)
    # the same rays: the source does not move
    np.testing.assert_allclose(region.source_mm, view.source_mm, atol=1e-9)


def test_the_whole_detector_at_a_scale_is_view_scaled(view):
    full = crop_view(view, (0, 960, 0, 1240), 0.5)
    scaled = view.scaled(0.5)
    assert full.shape == scaled.shape
    np.testing.assert_allclose(full.P, scaled.P, rtol=0, atol=1e-12 * np.abs(scaled.P).max())


def test_the_region_holds_the_projected_model_with_its_margin_aligned(view, points):
    T = POSES[0]
    region = region_of_interest(view, points, T, margin_px=20, align_px=32, scale=0.5)
    assert isinstance(region, RegionOfInterest)
    r0, r1, c0, c1 = region.box
    uv = view.project(points @ T[:3, :3].T + T[:3, 3])
    on = view.in_image(uv)
    rows, cols = view.shape
    # every projected point on the detector lies in the box, at least the margin inside unless clipped
    assert uv[on, 0].min() - 20 >= c0 or c0 == 0
    assert uv[on, 1].min() - 20 >= r0 or r0 == 0
    assert uv[on, 0].max() + 20 <= c1 or c1 == cols
    assert uv[on, 1].max() + 20 <= r1 or r1 == rows
    assert all(b % 32 == 0 or b in (rows, cols) for b in region.box)
    assert region.view.shape == ((r1 - r0) // 2, (c1 - c0) // 2) and region.frame_shape == view.shape
    assert 0 < region.area_fraction <= 1 and not region.full_frame
    # a wider margin never gives a smaller box
    wider = region_of_interest(view, points, T, margin_px=80, align_px=32, scale=0.5)
    assert wider.box[0] <= r0 and wider.box[2] <= c0 and wider.box[1] >= r1 and wider.box[3] >= c1


def test_a_pose_off_the_detector_gives_the_whole_detector(view, points):
    T = POSES[0].copy()
    T[:3, 3] += [0.0, 0.0, 2000.0]  # far above the field of view
    region = region_of_interest(view, points, T, margin_px=10, align_px=32, scale=0.5)
    assert region.full_frame and region.box == (0, 960, 0, 1240)


def test_bad_input_is_refused_naming_the_argument(view, points):
    with pytest.raises(ValueError, match="scale must be 1/k"):
        crop_view(view, (0, 64, 0, 64), 0.3)
    with pytest.raises(ValueError, match="box must be 4 integers"):
        crop_view(view, (0, 64, 0), 0.5)
    with pytest.raises(ValueError, match="must lie in the detector"):
        crop_view(view, (0, 2000, 0, 64), 1.0)
    with pytest.raises(ValueError, match="multiples of 1/scale = 4"):
        crop_view(view, (0, 64, 2, 66), 0.25)
    with pytest.raises(TypeError, match="view must be"):
        crop_view("A", (0, 64, 0, 64))
    with pytest.raises(ValueError, match="align_px must be a positive integer multiple of 1/scale = 2"):
        region_of_interest(view, points, POSES[0], margin_px=10, align_px=31, scale=0.5)
    with pytest.raises(ValueError, match="margin_px must be"):
        region_of_interest(view, points, POSES[0], margin_px=-1, align_px=32)
    with pytest.raises(ValueError, match="T_carm_transducer must be a finite 4x4"):
        region_of_interest(view, points, np.eye(3), margin_px=10, align_px=32)
