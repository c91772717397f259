"""Compiled point splatting on the CPU (§II-B.2): the jitter drawn, projected and binned in one pass, with a
counter-based stream per point and fixed parts summed in order, so a seed gives the same bits on any
number of threads (docs/imaging.md, "Splatting")."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__: list[str] = []

#: Fixed number of partial images (the image's bits do not depend on the thread count).
N_PARTS = 4

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S32 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(32)
_LOW32 = np.uint64(0xFFFFFFFF)


def _ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(kn, wn, fn)`` of Marsaglia & Tsang's 128-layer ziggurat for the standard normal."""
    r, v = 3.442619855899, 9.91256303526217e-3
    m1 = 2147483648.0
    kn, wn, fn = np.zeros(128, np.int64), np.zeros(128), np.zeros(128)
    dn = tn = r
    q = v / math.exp(-0.5 * dn * dn)
    kn[0], kn[1] = int((dn / q) * m1), 0
    wn[0], wn[127] = q / m1, dn / m1
    fn[0], fn[127] = 1.0, math.exp(-0.5 * dn * dn)
    for i in range(126, 0, -1):
        dn = math.sqrt(-2.0 * math.log(v / dn + math.exp(-0.5 * dn * dn)))
        kn[i + 1] = int((dn / tn) * m1)
        tn = dn
        fn[i] = math.exp(-0.5 * dn * dn)
        wn[i] = dn / m1
    return kn, wn, fn


_KN, _WN, _FN = _ziggurat_tables()
_R = 3.442619855899


@numba.njit(inline="always")
def _mix(z):
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@numba.njit(inline="always")
def _stream_start(seed, index):
    return _mix(seed + (np.uint64(index) + np.uint64(1)) * _GAMMA)


@numba.njit(inline="always")
def _signed32(bits):
    """The low 32 bits of ``bits`` as a signed integer (int64)."""
    value = np.int64(bits & _LOW32)
    return value - np.int64(4294967296) if value >= np.int64(2147483648) else value


@numba.njit(inline="always")
def _uniform(state, spare, have_spare):
    """A uniform on (0, 1) from the stream's next 32 bits; returns (u, state, spare, have_spare)."""
    bits, state, spare, have_spare = _next32(state, spare, have_spare)
    return ((bits & _LOW32) + 0.5) / 4294967296.0, state, spare, have_spare


@numba.njit(inline="always")
def _next32(state, spare, have_spare):
    """The stream's next 32 random bits (in a uint64), two per SplitMix64 output."""
    if have_spare:
        return spare, state, spare, False
    state = state + _GAMMA
    z = _mix(state)
    return z & _LOW32, state, z >> _S32, True


@numba.njit(inline="always")
def _normal(state, spare, have_spare, kn, wn, fn):
    """A standard normal (float64) from the stream; returns (x, state, spare, have_spare)."""
    bits, state, spare, have_spare = _next32(state, spare, have_spare)
    hz = _signed32(bits)
    iz = hz & 127
    if abs(hz) < kn[iz]:
        return hz * wn[iz], state, spare, have_spare
    while True:
        x = hz * wn[iz]
        if iz == 0:
            # the tail beyond r: Marsaglia (1964)
            while True:
                u1, state, spare, have_spare = _uniform(state, spare, have_spare)
                u2, state, spare, have_spare = _uniform(state, spare, have_spare)
                x = -math.log(u1) / _R
                y = -math.log(u2)
                if y + y >= x * x:
                    break
            return (_R + x if hz > 0 else -_R - x), state, spare, have_spare
        u, state, spare, have_spare = _uniform(state, spare, have_spare)
        if fn[iz] + u * (fn[iz - 1] - fn[iz]) < math.exp(-0.5 * x * x):
            return x, state, spare, have_spare
        bits, state, spare, have_spare = _next32(state, spare, have_spare)
        hz = _signed32(bits)
        iz = hz & 127
        if abs(hz) < kn[iz]:
            return hz * wn[iz], state, spare, have_spare


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def standard_normals(seed, n_points, per_point):
    """``(n_points, per_point)`` float32: the first ``per_point`` normals of each point's stream."""
    out = np.empty((n_points, per_point), dtype=np.float32)
    kn, wn, fn = _KN, _WN, _FN
    s = np.uint64(seed)
    for i in numba.prange(n_points):
        state, spare, have_spare = _stream_start(s, i), np.uint64(0), False
        for k in range(per_point):
            x, state, spare, have_spare = _normal(state, spare, have_spare, kn, wn, fn)
            out[i, k] = np.float32(x)
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def splat_into(partial, points, weights, first_index, A, det_M, source, M, sigma, n_splats, seed, rows, cols):
    """Add one class's splat copies to the ``(N_PARTS, rows * cols)`` float64 ``partial`` images.

    Per point ``p`` (mm, transducer frame) of non-zero weight, as :func:`~._device.splat_points`
    and the numpy reference: ``uvw = A [p, 1]`` (``A = P [R t]``, float64); points with ``w <= 0``
    are skipped; the footprint is ``|w|^3 / (|det M| |p - source|)`` mm² (``source`` in the
    transducer frame) and a copy adds ``weight / (n_splats * footprint)``. Copy ``k`` is jittered
    in float32 by ``sigma`` times the normals ``3k .. 3k + 2`` of stream ``first_index + i`` (the
    point's index among all the model's points), projected by ``M = P[:, :3]`` (float32) and added
    to its nearest pixel if it lands on the detector. The points are cut into ``N_PARTS``
    contiguous parts, part ``j`` added to ``partial[j]``.
    """
    m = points.shape[0]
    kn, wn, fn = _KN, _WN, _FN
    s = np.uint64(seed)
    half = np.float32(0.5)
    for part in numba.prange(N_PARTS):
        image = partial[part]
        for i in range(part * m // N_PARTS, (part + 1) * m // N_PARTS):
            weight = weights[i]
            if not weight > 0:
                continue
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            w64 = A[2, 0] * px + A[2, 1] * py + A[2, 2] * pz + A[2, 3]
            if not w64 > 0:
                continue
            u64 = A[0, 0] * px + A[0, 1] * py + A[0, 2] * pz + A[0, 3]
            v64 = A[1, 0] * px + A[1, 1] * py + A[1, 2] * pz + A[1, 3]
            distance = math.sqrt((px - source[0]) ** 2 + (py - source[1]) ** 2 + (pz - source[2]) ** 2)
            value = weight / (n_splats * (w64 ** 3 / (det_M * distance)))
            b0, b1, b2 = np.float32(u64), np.float32(v64), np.float32(w64)
            state, spare, have_spare = _stream_start(s, first_index + i), np.uint64(0), False
            for _ in range(n_splats):
                h0, h1, h2 = b0, b1, b2
                if sigma > 0:
                    x, state, spare, have_spare = _normal(state, spare, have_spare, kn, wn, fn)
                    y, state, spare, have_spare = _normal(state, spare, have_spare, kn, wn, fn)
                    z, state, spare, have_spare = _normal(state, spare, have_spare, kn, wn, fn)
                    ox, oy, oz = np.float32(x) * sigma, np.float32(y) * sigma, np.float32(z) * sigma
                    h0 = M[0, 0] * ox + M[0, 1] * oy + M[0, 2] * oz + b0
                    h1 = M[1, 0] * ox + M[1, 1] * oy + M[1, 2] * oz + b1
                    h2 = M[2, 0] * ox + M[2, 1] * oy + M[2, 2] * oz + b2
                if not h2 > 0:
                    continue
                col = h0 / h2 + half
                row = h1 / h2 + half
                if col >= 0 and col < cols and row >= 0 and row < rows:
                    image[np.int64(row) * cols + np.int64(col)] += value


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def mark_nearest_pixels(mask, points, R, t, P, source, det_M, rows, cols):
    """Set ``mask[pixel] = 1`` (flat ``(rows * cols,)`` uint8) for the nearest pixel of every point
    ``(n, 3)`` mm (transducer frame) that lands on the detector; return the smallest pixel
    footprint (mm², :meth:`~histostudy.imaging.carm.View.pixel_footprint_mm2`) among those points,
    ``inf`` if none lands.

    The label renderer's projection (:func:`~histostudy.imaging.render._reference.render_labels`) in float64:
    world ``= R p + t``, ``uvw = P [world, 1]``, pixel ``floor(u / w + 0.5)`` as carm's convention.
    """
    smallest = np.inf
    for i in numba.prange(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        w = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
        if not w > 0:
            continue
        col = (P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / w + 0.5
        row = (P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / w + 0.5
        if col >= 0 and col < cols and row >= 0 and row < rows:
            mask[np.int64(row) * cols + np.int64(col)] = 1
            distance = math.sqrt((x - source[0]) ** 2 + (y - source[1]) ** 2 + (z - source[2]) ** 2)
            smallest = min(smallest, w ** 3 / (det_M * distance))
    return smallest
