"""Azimuth/elevation relative to a view, eq. 4 candidates, mirror selection, the oracle."""

import numpy as np
import pytest
import torch

from histostudy.geometry import make_transform
from histostudy.geometry.transforms import random_rotation
from histostudy.imaging import Frame, View, default_biplane
from histostudy.learning import (
    LearnedOrientation,
    OracleOrientation,
    OrientationSource,
    angles_from_direction,
    beam_direction_of_pose,
    direction_candidates,
    orientation_angle_error,
    select_direction,
    wrap_angle,
)
from histostudy.learning.orientation import (
    N_ORIENTATION_CLASSES,
    hemisphere_angles,
    hemisphere_directions,
    orientation_class,
)


def _random_directions(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("view", default_biplane() + (View.from_gantry(20, 30),), ids=lambda v: v.name or "oblique")
def test_angles_round_trip_through_eq4_up_to_the_mirror(view):
    for d in _random_directions(50):
        az, el = angles_from_direction(d, view)
        assert -np.pi <= az <= np.pi and 0 <= el <= np.pi / 2
        cands = direction_candidates(az, el, view)
        assert np.allclose(np.linalg.norm(cands, axis=1), 1)
        # one candidate is d; the other is d mirrored on the detector plane
        errs = [np.linalg.norm(c - d) for c in cands]
        assert min(errs) < 1e-9
        mirrored = d - 2 * (d @ view.detector_axes[2]) * view.detector_axes[2]
        assert min(np.linalg.norm(c - mirrored) for c in cands) < 1e-9
        # candidate 0 points away from the detector
        assert cands[0] @ view.detector_axes[2] <= 1e-12


def test_elevation_is_the_angle_to_the_beam():
    view = View.from_gantry(0, 0)
    beam = view.detector_axes[2]
    assert angles_from_direction(-beam, view)[1] == pytest.approx(0.0, abs=1e-7)
    assert angles_from_direction(beam, view)[1] == pytest.approx(0.0, abs=1e-7)  # mirror
    az, el = angles_from_direction(view.detector_axes[0], view)
    assert (az, el) == pytest.approx((0.0, np.pi / 2))
    az, _ = angles_from_direction(view.detector_axes[1], view)
    assert az == pytest.approx(np.pi / 2)


def test_two_views_resolve_the_mirror_ambiguity():
    a, b = default_biplane()
    for d in _random_directions(100, seed=1):
        cands = [direction_candidates(*angles_from_direction(d, v), v) for v in (a, b)]
        chosen, idx, spread = select_direction(cands)
        assert np.allclose(chosen, d, atol=1e-9) and spread < 1e-7


def test_one_view_returns_the_canonical_candidate():
    a = default_biplane()[0]
    cands = direction_candidates(0.3, 0.4, a)
    chosen, idx, spread = select_direction([cands])
    assert idx == (0,) and np.allclose(chosen, cands[0])
    with pytest.raises(ValueError, match="at least one view"):
        select_direction([])


def test_wrap_angle():
    assert wrap_angle(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)
    assert np.allclose(wrap_angle([0.1, 2 * np.pi + 0.1]), [0.1, 0.1])


def test_oracle_errors_have_the_papers_mean_absolute_error():
    view = default_biplane()[0]
    rng = np.random.default_rng(5)
    oracle = OracleOrientation()
    az_err, el_err = [], []
    for _ in range(600):
        R = random_rotation(rng)
        T = make_transform(R, [0, 0, 0])
        az0, el0 = angles_from_direction(beam_direction_of_pose(T), view)
        if not (0.2 < el0 < 1.3):  # away from the fold at 0 and the azimuth singularity
            continue
        frame = Frame(np.zeros(view.shape, np.float32), view, T_carm_transducer=T)
        az, el = oracle.estimate(frame, rng)
        az_err.append(np.rad2deg(abs(wrap_angle(az - az0))))
        el_err.append(np.rad2deg(abs(el - el0)))
    assert np.mean(az_err) == pytest.approx(1.06, rel=0.15)
    assert np.mean(el_err) == pytest.approx(2.34, rel=0.15)


def test_oracle_is_deterministic_and_needs_truth():
    view = default_biplane()[1]
    T = make_transform(random_rotation(np.random.default_rng(0)), [0, 0, 0])
    frame = Frame(np.zeros(view.shape, np.float32), view, T_carm_transducer=T)
    o = OracleOrientation()
    assert o.estimate(frame, np.random.default_rng(3)) == o.estimate(frame, np.random.default_rng(3))
    with pytest.raises(ValueError, match="T_carm_transducer"):
        o.estimate(Frame(np.zeros(view.shape, np.float32), view), np.random.default_rng(0))
    with pytest.raises(ValueError, match="azimuth_mae_deg"):
        OracleOrientation(azimuth_mae_deg=-1)


# --- the learned stage: hemisphere classes and the regressor ------------------------------------


def test_36_hemisphere_directions_point_away_and_are_near_equidistant():
    d = hemisphere_directions()
    assert d.shape == (N_ORIENTATION_CLASSES, 3) == (36, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.all(d[:, 2] < 0)
    cos = d @ d.T
    np.fill_diagonal(cos, -1)
    nearest = np.degrees(np.arccos(cos.max(axis=1)))
    # 36 points on 2 pi sr: ~0.175 sr each, a spacing of ~ sqrt(0.175) rad = 24 deg
    assert nearest.min() > 14 and nearest.max() < 30
    # equal areas: as many directions above as below 60 deg elevation (half the hemisphere's area)
    assert np.sum(hemisphere_angles()[:, 1] < np.radians(60)) == 18


def test_orientation_class_is_the_nearest_direction():
    a = hemisphere_angles()
    for k in range(36):
        assert orientation_class(*a[k]) == k
    rng = np.random.default_rng(5)
    d = hemisphere_directions()
    for _ in range(20):
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(0, np.pi / 2)
        v = np.array([np.cos(az) * np.sin(el), np.sin(az) * np.sin(el), -np.cos(el)])
        assert orientation_class(az, el) == int(np.argmin(np.linalg.norm(d - v, axis=1)))


def test_orientation_angle_error_is_the_angle_between_the_eq4_directions():
    view = View.from_gantry(20, 30)
    rng = np.random.default_rng(8)
    for _ in range(20):
        a, b = rng.uniform(-np.pi, np.pi, 2), rng.uniform(0, np.pi / 2, 2)
        da, db = direction_candidates(a[0], b[0], view)[0], direction_candidates(a[1], b[1], view)[0]
        expected = np.arccos(np.clip(da @ db, -1, 1))
        assert orientation_angle_error(a[0], b[0], a[1], b[1]) == pytest.approx(expected, abs=1e-9)
    # Elevation alone: its difference. Near elevation 0 a large azimuth error is a small direction error.
    assert orientation_angle_error(0.3, 0.5, 0.3, 0.2) == pytest.approx(0.3)
    assert np.rad2deg(orientation_angle_error(0.0, np.deg2rad(2), np.pi, np.deg2rad(2))) == pytest.approx(4.0)
    np.testing.assert_allclose(orientation_angle_error(np.zeros(3), np.full(3, 0.4), np.zeros(3), np.full(3, 0.4)), 0,
                               atol=1e-7)


class _ConstantNet(torch.nn.Module):
    def __init__(self, az, el):
        super().__init__()
        self.out = torch.tensor([az, el], dtype=torch.float32)

    def forward(self, x):
        assert x.shape[1:] == (1, 240, 310)  # the paper's 310x240 input
        return self.out.expand(x.shape[0], 2)


def test_learned_orientation_wraps_and_folds_the_network_output():
    view = default_biplane()[0]
    frame = Frame(np.zeros(view.shape, np.float32), view)
    src = LearnedOrientation(_ConstantNet(4.0, -0.3))
    assert isinstance(src, OrientationSource)
    az, el = src.estimate(frame, np.random.default_rng(0))
    assert az == pytest.approx(4.0 - 2 * np.pi, abs=1e-6) and el == pytest.approx(0.3, abs=1e-6)
    az, el = LearnedOrientation(_ConstantNet(0.5, 2.0)).estimate(frame, None)
    assert el == pytest.approx(np.pi - 2.0, abs=1e-6)
    with pytest.raises(TypeError, match="Frame"):
        src.estimate(np.zeros(view.shape), None)
