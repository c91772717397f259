"""The C-arm's geometry against its calibration: miscalibrated and displaced views."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import View, default_biplane
from histostudy.imaging.carm_errors import displaced_view, miscalibrated_view


@pytest.fixture(scope="module")
def view():
    return default_biplane()[0]


def _detector_points(view: View, n: int = 6) -> np.ndarray:
    """World points on the detector plane (at the source-detector distance along the principal ray)."""
    K, R, source = view.decomposition
    focal_mm = K[0, 0] * view.pixel_mm
    rng = np.random.default_rng(0)
    offsets = rng.uniform(-100, 100, (n, 2))
    return source + focal_mm * R[2] + offsets[:, :1] * R[0] + offsets[:, 1:] * R[1]


def test_zero_errors_keep_the_geometry(view):
    same = miscalibrated_view(view)
    pts = np.random.default_rng(1).uniform(-50, 50, (20, 3))
    assert np.allclose(same.project(pts), view.project(pts), atol=1e-9)


def test_moving_the_source_keeps_the_detector(view):
    offset = np.array([1.5, -0.7, 2.0])
    moved = miscalibrated_view(view, source_offset_mm=offset)
    assert np.allclose(moved.source_mm, view.source_mm + offset, atol=1e-9)
    on_detector = _detector_points(view)
    assert np.allclose(moved.project(on_detector), view.project(on_detector), atol=1e-7)
    # a point near the isocentre moves: by about the offset across the ray times (1 - magnification)
    iso = np.zeros((1, 3))
    shift_px = np.linalg.norm(moved.project(iso) - view.project(iso))
    assert 0.5 < shift_px < 5.0


def test_principal_point_shift_moves_every_pixel_alike(view):
    moved = miscalibrated_view(view, detector_shift_px=(0.4, -0.25))
    pts = np.random.default_rng(2).uniform(-50, 50, (20, 3))
    assert np.allclose(moved.project(pts) - view.project(pts), [0.4, -0.25], atol=1e-9)


def test_displaced_view_sees_moved_points_where_the_calibration_saw_them(view):
    T = make_transform(matrix_from_rotvec([0.001, -0.002, 0.0005]), [0.3, 0.8, -0.2])
    moved = displaced_view(view, T)
    pts = np.random.default_rng(3).uniform(-50, 50, (20, 3))
    moved_pts = pts @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(moved.project(moved_pts), view.project(pts), atol=1e-9)
    assert np.allclose(moved.source_mm, T[:3, :3] @ view.source_mm + T[:3, 3], atol=1e-6)


def test_bad_inputs_name_the_argument(view):
    with pytest.raises(ValueError, match="source_offset_mm"):
        miscalibrated_view(view, source_offset_mm=(1.0, 2.0))
    with pytest.raises(ValueError, match="detector_shift_px"):
        miscalibrated_view(view, detector_shift_px=(np.nan, 0.0))
    with pytest.raises(ValueError, match="half its distance"):
        miscalibrated_view(view, source_offset_mm=-900.0 * view.principal_direction)
    with pytest.raises(ValueError, match="T_world_motion"):
        displaced_view(view, np.eye(3))
    with pytest.raises(TypeError, match="view"):
        miscalibrated_view("A")
