"""Tests of histostudy.calibration.dual_quaternion: conventions, composition, and the batched
quaternions against SciPy's (through histostudy.geometry), also near 180 degrees."""

import numpy as np
import pytest

from histostudy.calibration import dual_quaternion as dq
from histostudy.geometry import transforms as g


@pytest.mark.parametrize("seed", range(5))
def test_dual_quaternion_conventions(seed):
    rng = np.random.default_rng(seed)
    T1, T2 = g.random_transform(rng, 300.0), g.random_transform(rng, 300.0)
    d1, d2 = dq.dual_quaternion_from_transform(T1), dq.dual_quaternion_from_transform(T2)
    # real part: geometry's (SciPy's) quaternion, scalar first, w >= 0
    assert np.allclose(d1[:4], g.quaternion_from_matrix(T1[:3, :3]), atol=1e-14)
    # unit dual quaternion: q.q = 1, q.q' = 0, and the dual part carries t: q' = 1/2 t q
    assert np.isclose(d1[:4] @ d1[:4], 1.0) and abs(d1[:4] @ d1[4:]) < 1e-12
    assert np.allclose(dq.transform_from_dual_quaternion(d1), T1, atol=1e-12)
    assert np.allclose(dq.transform_from_dual_quaternion(-d1), T1, atol=1e-12)
    # products compose like matrices (up to the sign of the representative)
    q = dq.quaternion_product(d1[:4], d2[:4])
    qd = dq.quaternion_product(d1[:4], d2[4:]) + dq.quaternion_product(d1[4:], d2[:4])
    d12 = dq.dual_quaternion_from_transform(T1 @ T2)
    s = np.sign(q @ d12[:4])
    assert np.allclose(s * np.concatenate([q, qd]), d12, atol=1e-10)


def test_batched_quaternions_match_scipy_also_near_180_degrees():
    rng = np.random.default_rng(7)
    Rs = [g.random_rotation(rng) for _ in range(50)]
    Rs += [g.rotation_about_axis(rng.normal(size=3), np.pi - eps) for eps in (0.0, 1e-12, 1e-6, 1e-3)]
    Rs += [np.eye(3), g.rotation_about_axis([1, 0, 0], np.pi)]
    q = dq.quaternions_from_matrices(np.array(Rs))
    for qi, R in zip(q, Rs):
        ref = g.quaternion_from_matrix(R)
        # at exactly 180 deg w = 0 and either sign is the rotation; compare up to sign
        assert min(np.abs(qi - ref).max(), np.abs(qi + ref).max()) < 1e-12
        assert np.allclose(g.matrix_from_quaternion(qi), R, atol=1e-12)
