"""Tests of histostudy.transducer.physical: the physical model's quadrant deviations and extra screws (§IV)."""

import numpy as np
import pytest

from histostudy.geometry import check_rigid, rotvec_from_matrix
from histostudy.transducer import FEATURE_CLASSES, Feature, ManufacturingDeviation, TransducerModel, TransducerSpec
from histostudy.transducer.spec import quadrant_index

SPEC = TransducerSpec()
R = 138.7


def test_physical_model_is_seed_deterministic():
    a = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))
    b = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))
    c = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(4))
    for f in FEATURE_CLASSES:
        assert np.array_equal(a.points[f], b.points[f]) and np.array_equal(a.weights[f], b.weights[f])
    assert not np.array_equal(a.points[Feature.TRANSDUCER], c.points[Feature.TRANSDUCER])
    np.testing.assert_array_equal(a.focal_point_mm, b.focal_point_mm)


def test_physical_quadrants_move_rigidly_and_focal_point_follows():
    digital = TransducerModel.build(spacing_mm=1.0)
    phys = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0))
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.GAPS):
        d, p = digital.points[f], phys.points[f]
        q = quadrant_index(d)
        for k in range(4):
            T = check_rigid(phys.quadrant_transforms[k])
            np.testing.assert_allclose(p[q == k], d[q == k] @ T[:3, :3].T + T[:3, 3], atol=1e-9)
    np.testing.assert_allclose(phys.focal_point_mm, phys.quadrant_transforms[:, :3, 3].mean(axis=0))
    assert 0 < np.linalg.norm(phys.focal_point_mm) < 2.0


def test_physical_deviation_has_the_requested_size():
    """Pooled over seeds, recovered quadrant offsets and tilts have the requested SDs."""
    offsets, tilts = [], []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        shift = TransducerModel.build_physical(spacing_mm=4.0, rng=rng, deviation=ManufacturingDeviation(
            quadrant_offset_sd_mm=0.2, quadrant_tilt_sd_deg=0.0, extra_screw_count=0))
        digital = TransducerModel.build(spacing_mm=4.0)
        d, p = digital.points[Feature.TRANSDUCER], shift.points[Feature.TRANSDUCER]
        q = quadrant_index(d)
        offsets += [(p[q == k] - d[q == k]).mean(axis=0) for k in range(4)]
        tilt = TransducerModel.build_physical(spacing_mm=4.0, rng=rng, deviation=ManufacturingDeviation(
            quadrant_offset_sd_mm=0.0, quadrant_tilt_sd_deg=0.15, extra_screw_count=0))
        tilts += [rotvec_from_matrix(_kabsch(d[q == k], tilt.points[Feature.TRANSDUCER][q == k])) for k in range(4)]
    assert np.std(offsets) == pytest.approx(0.2, rel=0.2)
    assert np.rad2deg(np.std(tilts)) == pytest.approx(0.15, rel=0.2)


def _kabsch(src, dst):
    a, b = src - src.mean(axis=0), dst - dst.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1, 1, d]) @ u.T


def test_zero_deviation_equals_digital_and_extra_screws_sit_beyond_the_apex():
    digital = TransducerModel.build(spacing_mm=1.0)
    none = ManufacturingDeviation(quadrant_offset_sd_mm=0, quadrant_tilt_sd_deg=0, extra_screw_count=0)
    same = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0), deviation=none)
    for f in FEATURE_CLASSES:
        np.testing.assert_allclose(same.points[f], digital.points[f], atol=1e-12)
    three = ManufacturingDeviation(quadrant_offset_sd_mm=0, quadrant_tilt_sd_deg=0, extra_screw_count=3)
    extra = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0), deviation=three)
    n_dig = digital.n_points[Feature.SCREWS]
    new = extra.points[Feature.SCREWS][n_dig:]
    assert len(new) == 3 * n_dig // SPEC.screw_count
    assert np.all(new[:, 2] > R)
