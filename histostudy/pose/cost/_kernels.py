"""The fused numba kernels behind :class:`~._model.PoseCost` (§II-B.3, eq. 3 and its Jacobian),
serial and on numba's threads (the same bits either way), each releasing the GIL. Points in mm
(transducer frame), distances in pixels; the Jacobian is with respect to the left perturbation
``[w (rad), v (mm)]`` of :mod:`histostudy.pose.perturbation`. Internal to ``PoseCost``.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = []

#: Points per block of the fused kernels: each block sums serially, the blocks in parallel, and the
#: block sums are added in order, so results are bit-identical whatever the thread count.
BLOCK_POINTS = 1024

# Shared arguments:
#   pts (N, 3) f8: model points in the transducer frame, grouped by class (enum order).
#   tasks (n_tasks, 5) i8: rows (view a, class slot s, map start, first point, end point): the
#       points of one class in one view where that class is active, in blocks of at most
#       BLOCK_POINTS points. Blocks run in parallel; each writes its own partial sum, added in
#       task order afterwards, so a result is the same bits whatever the number of threads.
#   M (A, 3, 3), c (A, 3) f8: per view, P[:, :3] @ R and P[:, :3] @ t + P[:, 3], so that
#       [u w, v w, w] = M p + c (the pose folded into the projection: 9 mul-adds per point and view).
#   maps (total,) f4: the active distance maps, flattened; rows, cols (A,) i8.
#   wt (A, K) f8 = lambda_k / n_k; outside_sq = 0.1²; cap f8: distances are capped at it (inf: none).
#
# Each block runs in two loops: a branch-free one that projects the points and computes the
# bilinear cell index and fractions (LLVM vectorises it, divisions included: it reads the block
# through a slice, whose indices cannot be negative, and the kernels use numpy's error model, where
# 1 / 0 is inf rather than a ZeroDivisionError branch; w == 0 is then outside), then the look-ups.
# Points outside the map are clamped to a valid cell (so every load is in bounds) and weighted 0.


@numba.njit(inline="always")
def _locate_block(pts, i0, m, M, c, a, base, rows_a, cols_a, cell, fxb, fyb, inb, ub, vb, iwb):
    """Bilinear cell (flat index of its top-left pixel), fractions, inside flag (1.0 / 0.0), u, v and
    1/w of points i0 .. i0+m-1 in view a."""
    m00, m01, m02 = M[a, 0, 0], M[a, 0, 1], M[a, 0, 2]
    m10, m11, m12 = M[a, 1, 0], M[a, 1, 1], M[a, 1, 2]
    m20, m21, m22 = M[a, 2, 0], M[a, 2, 1], M[a, 2, 2]
    c0, c1, c2 = c[a, 0], c[a, 1], c[a, 2]
    u_hi, v_hi = cols_a - 0.5, rows_a - 0.5
    u_cl, v_cl = cols_a - 1.0, rows_a - 1.0
    block = pts[i0:i0 + m]
    for j in range(m):
        x = block[j, 0]
        y = block[j, 1]
        z = block[j, 2]
        hw = m20 * x + m21 * y + m22 * z + c2
        iw = 1.0 / hw
        u = (m00 * x + m01 * y + m02 * z + c0) * iw
        v = (m10 * x + m11 * y + m12 * z + c1) * iw
        # View.in_image, and in front of the source; NaN (w == 0) compares False: outside.
        inside = (hw > 0.0) & (u >= -0.5) & (u < u_hi) & (v >= -0.5) & (v < v_hi)
        # Clamp to the outermost pixel centres: the half-pixel rim takes the edge value (NaN -> 0).
        uc = u if u > 0.0 else 0.0
        uc = uc if uc < u_cl else u_cl
        vc = v if v > 0.0 else 0.0
        vc = vc if vc < v_cl else v_cl
        x0 = min(int(uc), cols_a - 2)
        y0 = min(int(vc), rows_a - 2)
        cell[j] = base + y0 * cols_a + x0
        fxb[j] = uc - x0
        fyb[j] = vc - y0
        inb[j] = 1.0 if inside else 0.0
        ub[j] = u
        vb[j] = v
        iwb[j] = iw


@numba.njit(inline="always")
def _interpolate(maps, cell, stride, fx, fy, cap):
    """Bilinear distance and its exact gradient inside the cell, (d, dd/dfx, dd/dfy), of the map
    capped at ``cap`` pixels (each corner is capped before interpolating, as in
    :meth:`DistanceMaps.truncated`; ``inf`` for no cap)."""
    # Unsigned indices spare numba's negative-index wrap-around test on each load.
    i00 = np.uint64(cell)
    one = np.uint64(1)
    su = np.uint64(stride)
    d00 = min(np.float64(maps[i00]), cap)
    d10 = min(np.float64(maps[i00 + one]), cap)
    d01 = min(np.float64(maps[i00 + su]), cap)
    d11 = min(np.float64(maps[i00 + su + one]), cap)
    top = d00 + fx * (d10 - d00)
    bottom = d01 + fx * (d11 - d01)
    return top + fy * (bottom - top), (1.0 - fy) * (d10 - d00) + fy * (d11 - d01), bottom - top


@numba.njit(inline="always")
def _located_task(ti, pts, tasks, M, c, rows, cols):
    """Task ``ti``'s view ``a``, class ``s``, first point ``i0`` and number of points ``m``, and its
    block located in view ``a`` (:func:`_locate_block`'s cells, fractions, inside flags, u, v, 1/w)."""
    a, s, base, i0, i1 = tasks[ti, 0], tasks[ti, 1], tasks[ti, 2], tasks[ti, 3], tasks[ti, 4]
    m = i1 - i0
    cell = np.empty(BLOCK_POINTS, dtype=np.int64)
    fxb = np.empty(BLOCK_POINTS)
    fyb = np.empty(BLOCK_POINTS)
    inb = np.empty(BLOCK_POINTS)
    ub = np.empty(BLOCK_POINTS)
    vb = np.empty(BLOCK_POINTS)
    iwb = np.empty(BLOCK_POINTS)
    _locate_block(pts, i0, m, M, c, a, base, rows[a], cols[a], cell, fxb, fyb, inb, ub, vb, iwb)
    return a, s, i0, m, cell, fxb, fyb, inb, ub, vb, iwb


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    """Eq. 3's contribution of one task (one block of one class in one view)."""
    a, s, i0, m, cell, fxb, fyb, inb, ub, vb, iwb = _located_task(ti, pts, tasks, M, c, rows, cols)
    total = 0.0
    n_out = 0.0
    for j in range(m):
        d, gu, gv = _interpolate(maps, cell[j], cols[a], fxb[j], fyb[j], cap)
        total += inb[j] * (d * d)
        n_out += 1.0 - inb[j]
    return wt[a, s] * (total + n_out * outside_sq)


@numba.njit(parallel=True, fastmath=False, cache=True, nogil=True, error_model="numpy")
def cost_parallel(pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    partial = np.zeros(tasks.shape[0])
    for ti in numba.prange(tasks.shape[0]):
        partial[ti] = _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap)
    out = 0.0
    for ti in range(tasks.shape[0]):
        out += partial[ti]
    return out


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def cost_serial(pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap):
    out = 0.0
    for ti in range(tasks.shape[0]):
        out += _task_cost(ti, pts, tasks, M, c, maps, rows, cols, wt, outside_sq, cap)
    return out


@numba.njit(parallel=True, fastmath=False, cache=True, nogil=True, error_model="numpy")
def costs_batch(pts, tasks, M, c_all, maps, rows, cols, wt, outside_sq, cap):
    """:func:`cost_serial` at each of the translations folded into ``c_all`` (n, A, 3), in parallel
    over them; each is summed in task order, the same bits as one call per pose."""
    n = c_all.shape[0]
    out = np.empty(n)
    for k in numba.prange(n):
        total = 0.0
        for ti in range(tasks.shape[0]):
            total += _task_cost(ti, pts, tasks, M, c_all[k], maps, rows, cols, wt, outside_sq, cap)
        out[k] = total
    return out


@numba.njit(inline="always")
def _jacobian_row(R, P3, a, x, y, z, u, v, iw, gu, gv, sw, jrow):
    """``jrow = sw * dd/d[w, v]`` for one point: ``[q x g, g]`` with ``q = R p`` and ``g = dd/dX``.

    ``dd/dX = (gu (P0 - u P2) + gv (P1 - v P2)) / w`` with ``P0..P2`` the rows of the view's 3x3;
    a left rotation moves the world point by ``w x q``, hence ``dd/dw = q x g``.
    """
    qx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
    qy = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
    qz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
    s_ = sw * iw
    gx = s_ * (gu * (P3[a, 0, 0] - u * P3[a, 2, 0]) + gv * (P3[a, 1, 0] - v * P3[a, 2, 0]))
    gy = s_ * (gu * (P3[a, 0, 1] - u * P3[a, 2, 1]) + gv * (P3[a, 1, 1] - v * P3[a, 2, 1]))
    gz = s_ * (gu * (P3[a, 0, 2] - u * P3[a, 2, 2]) + gv * (P3[a, 1, 2] - v * P3[a, 2, 2]))
    jrow[0] = qy * gz - qz * gy
    jrow[1] = qz * gx - qx * gz
    jrow[2] = qx * gy - qy * gx
    jrow[3] = gx
    jrow[4] = gy
    jrow[5] = gz


@numba.njit(inline="always")
def _map_gradient(maps, cell, cols_a, rows_a, fx, fy, u, v, cap):
    """Distance and its gradient in pixels (d, dd/du, dd/dv); 0 across a clamped (rim) direction."""
    d, gu, gv = _interpolate(maps, cell, cols_a, fx, fy, cap)
    if not (u >= 0.0 and u <= cols_a - 1.0):
        gu = 0.0
    if not (v >= 0.0 and v <= rows_a - 1.0):
        gv = 0.0
    return d, gu, gv


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, out):
    """Cost, J^T J (upper triangle, 21) and J^T r (6) of one task into ``out`` (28,)."""
    a, s, i0, m, cell, fxb, fyb, inb, ub, vb, iwb = _located_task(ti, pts, tasks, M, c, rows, cols)
    acc = np.zeros(28)
    jrow = np.zeros(6)
    sw = np.sqrt(wt[a, s])
    n_out = 0.0
    for j in range(m):
        if inb[j] == 0.0:
            n_out += 1.0
            continue
        u, v = ub[j], vb[j]
        d, gu, gv = _map_gradient(maps, cell[j], cols[a], rows[a], fxb[j], fyb[j], u, v, cap)
        r = sw * d
        acc[0] += r * r
        i = i0 + j
        _jacobian_row(R, P3, a, pts[i, 0], pts[i, 1], pts[i, 2], u, v, iwb[j], gu, gv, sw, jrow)
        idx = 1
        for p in range(6):
            jp = jrow[p]
            for q in range(p, 6):
                acc[idx] += jp * jrow[q]
                idx += 1
        for p in range(6):
            acc[22 + p] += jrow[p] * r
    acc[0] += wt[a, s] * n_out * outside_sq
    for idx in range(28):
        out[idx] = acc[idx]


@numba.njit(parallel=True, fastmath=False, cache=True, nogil=True, error_model="numpy")
def normal_parallel(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap):
    """Cost, J^T J and J^T r in one pass; J (n x 6) is never built. Returns the 28 sums."""
    partial = np.zeros((tasks.shape[0], 28))
    for ti in numba.prange(tasks.shape[0]):
        _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, partial[ti])
    total = np.zeros(28)
    for ti in range(tasks.shape[0]):
        for idx in range(28):
            total[idx] += partial[ti, idx]
    return total


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def normal_serial(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap):
    part = np.zeros(28)
    total = np.zeros(28)
    for ti in range(tasks.shape[0]):
        _task_normal(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside_sq, cap, part)
        for idx in range(28):
            total[idx] += part[idx]
    return total


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    """Residuals and Jacobian rows of one task into ``r_out (A, N)`` and ``j_out (A, N, 6)``."""
    a, s, i0, m, cell, fxb, fyb, inb, ub, vb, iwb = _located_task(ti, pts, tasks, M, c, rows, cols)
    jrow = np.zeros(6)
    sw = np.sqrt(wt[a, s])
    for j in range(m):
        i = i0 + j
        if inb[j] == 0.0:
            r_out[a, i] = sw * outside
            continue
        u, v = ub[j], vb[j]
        d, gu, gv = _map_gradient(maps, cell[j], cols[a], rows[a], fxb[j], fyb[j], u, v, cap)
        r_out[a, i] = sw * d
        _jacobian_row(R, P3, a, pts[i, 0], pts[i, 1], pts[i, 2], u, v, iwb[j], gu, gv, sw, jrow)
        for p in range(6):
            j_out[a, i, p] = jrow[p]


@numba.njit(parallel=True, fastmath=False, cache=True, nogil=True, error_model="numpy")
def residual_parallel(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    """Residuals and Jacobian rows of the active (view, class) pairs; the caller zeroes both
    outputs beforehand (inactive pairs stay 0)."""
    for ti in numba.prange(tasks.shape[0]):
        _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out)


@numba.njit(fastmath=False, cache=True, nogil=True, error_model="numpy")
def residual_serial(pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out):
    for ti in range(tasks.shape[0]):
        _task_residual(ti, pts, tasks, R, M, c, P3, maps, rows, cols, wt, outside, cap, r_out, j_out)
