"""Tests of histostudy.pose.conic: a circle of known radius from its projected conic (exact answers)."""

import cv2
import numpy as np
import pytest

from histostudy.imaging import View
from histostudy.pose.conic import (
    EllipseFit,
    circle_poses_from_conic,
    conic_from_ellipse,
    conic_from_points,
    fit_ellipse_ransac,
)


def circle_points(centre, normal, radius, n=240):
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.asarray(centre, float) + radius * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)


def angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(abs(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_conic_from_ellipse_vanishes_on_the_ellipse_and_is_negative_inside():
    C = conic_from_ellipse((300.0, 200.0), (80.0, 30.0), 0.4)
    t = np.linspace(0, 2 * np.pi, 50)
    c, s = np.cos(0.4), np.sin(0.4)
    pts = np.column_stack([300 + 80 * np.cos(t) * c - 30 * np.sin(t) * s,
                           200 + 80 * np.cos(t) * s + 30 * np.sin(t) * c])
    h = np.column_stack([pts, np.ones(len(pts))])
    assert np.allclose(np.einsum("ij,jk,ik->i", h, C, h), 0, atol=1e-9)
    assert np.array([300.0, 200.0, 1.0]) @ C @ np.array([300.0, 200.0, 1.0]) == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="semi-axes"):
        conic_from_ellipse((0, 0), (10, -1), 0.0)


@pytest.mark.parametrize("primary_deg", [-45.0, 0.0, 45.0, 80.0])
def test_one_of_the_two_circles_is_the_true_circle(primary_deg):
    view = View.from_gantry(primary_deg, 10.0, shape=(960, 1240), name="A")
    rng = np.random.default_rng(int(primary_deg) + 100)
    for _ in range(5):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        if angle_deg(normal, view.principal_direction) > 80:  # nearly edge-on: a degenerate ellipse
            continue
        centre = rng.uniform(-60, 60, size=3)
        conic = conic_from_points(view.project(circle_points(centre, normal, 32.0)))
        poses = circle_poses_from_conic(conic, view, 32.0)
        assert len(poses) == 2
        errors = [(angle_deg(p.normal, normal), np.linalg.norm(p.centre_mm - centre)) for p in poses]
        best = min(errors)
        assert best[0] < 1e-5 and best[1] < 1e-5, errors
        for p in poses:
            # the normal faces the source, and both circles image to the same ellipse
            assert p.normal @ (view.source_mm - p.centre_mm) > 0
            px = view.project(circle_points(p.centre_mm, p.normal, 32.0))
            h = np.column_stack([px, np.ones(len(px))])
            residual = np.einsum("ij,jk,ik->i", h, conic, h) / np.linalg.norm(conic)
            assert np.max(np.abs(residual)) < 1e-8


def test_the_radius_sets_the_depth_along_the_ray():
    view = View.from_gantry(30.0, 0.0, shape=(960, 1240))
    centre, normal = np.array([10.0, -20.0, 5.0]), np.array([0.2, 1.0, 0.3])
    conic = conic_from_points(view.project(circle_points(centre, normal, 32.0)))
    true = min(circle_poses_from_conic(conic, view, 32.0), key=lambda p: angle_deg(p.normal, normal))
    doubled = min(circle_poses_from_conic(conic, view, 64.0), key=lambda p: angle_deg(p.normal, normal))
    assert np.allclose(doubled.centre_mm - view.source_mm, 2 * (true.centre_mm - view.source_mm))


def test_a_hyperbola_or_bad_arguments_are_refused():
    view = View.from_gantry(0.0, 0.0, shape=(960, 1240))
    hyperbola = np.diag([1.0, -1.0, -100.0])
    with pytest.raises(ValueError, match="not an ellipse"):
        circle_poses_from_conic(hyperbola, view, 32.0)
    with pytest.raises(ValueError, match="radius_mm"):
        circle_poses_from_conic(conic_from_ellipse((600, 480), (50, 40), 0.0), view, 0.0)
    with pytest.raises(ValueError, match="3x3"):
        circle_poses_from_conic(np.eye(2), view, 32.0)
    with pytest.raises(TypeError, match="View"):
        circle_poses_from_conic(np.eye(3), "A", 32.0)


def test_ransac_fit_ignores_outliers_and_matches_opencv_on_clean_points():
    rng = np.random.default_rng(5)
    t = rng.uniform(0, 2 * np.pi, 600)
    c, s = np.cos(0.7), np.sin(0.7)
    clean = np.column_stack([500 + 150 * np.cos(t) * c - 60 * np.sin(t) * s,
                             400 + 150 * np.cos(t) * s + 60 * np.sin(t) * c])
    band = clean + rng.normal(0, 1.5, clean.shape)  # a band a few pixels wide, as segmented
    outliers = rng.uniform([200, 100], [800, 700], size=(300, 2))
    fit = fit_ellipse_ransac(np.vstack([band, outliers]), np.random.default_rng(0), tolerance_px=4.0)
    assert isinstance(fit, EllipseFit)
    assert np.allclose(fit.centre_px, (500, 400), atol=0.6)
    assert np.allclose(fit.semi_axes_px, (150, 60), atol=0.8)
    assert abs(fit.angle_rad - 0.7) < 0.01
    assert 0.6 < fit.inlier_fraction < 0.75  # the band's points, not the outliers
    # the independent reference: OpenCV's direct fit of the clean points alone
    (u0, v0), (w, h), _ = cv2.fitEllipseDirect(clean.astype(np.float32))
    clean_fit = fit_ellipse_ransac(clean, np.random.default_rng(0), tolerance_px=1.0)
    assert np.allclose(clean_fit.centre_px, (u0, v0), atol=1e-3)
    assert np.allclose(sorted(clean_fit.semi_axes_px), sorted((w / 2, h / 2)), atol=1e-3)


def test_ransac_fit_is_seeded_and_checks_its_arguments():
    pts = np.random.default_rng(1).uniform(0, 100, size=(200, 2))
    a = fit_ellipse_ransac(pts, np.random.default_rng(3))
    b = fit_ellipse_ransac(pts, np.random.default_rng(3))
    assert a == b
    assert fit_ellipse_ransac(pts[:8], np.random.default_rng(0)) is None
    with pytest.raises(TypeError, match="Generator"):
        fit_ellipse_ransac(pts, 0)
    with pytest.raises(ValueError, match="tolerance_px"):
        fit_ellipse_ransac(pts, np.random.default_rng(0), tolerance_px=float("nan"))
    with pytest.raises(ValueError, match="iterations"):
        fit_ellipse_ransac(pts, np.random.default_rng(0), iterations=0)


def test_ransac_scores_hypotheses_as_the_sampson_distance_counts_them():
    # the compiled score of a hypothesis against numpy's Sampson distance (the refits' measure),
    # on integer pixel positions of a noisy band, for conics fitted to random samples of it
    from histostudy.pose.conic import _count_within_px, _fit_conic_cv, _sampson_distance

    rng = np.random.default_rng(11)
    t = rng.uniform(0, 2 * np.pi, 3000)
    pts = np.round(np.column_stack([300 + 90 * np.cos(t), 200 + 40 * np.sin(t)]) + rng.normal(0, 2, (3000, 2)))
    checked = 0
    for _ in range(100):
        C = _fit_conic_cv(pts[rng.choice(len(pts), 6, replace=False)].astype(np.float32))
        if C is None:
            continue
        for tolerance in (1.0, 3.0, 6.5):
            assert _count_within_px(C, pts, tolerance) == np.count_nonzero(_sampson_distance(C, pts) <= tolerance)
        checked += 1
    assert checked > 80
