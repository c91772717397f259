"""The plain numpy float64 reference of eq. 3 (§II-B.3) for one view and one feature class, which
the tests compare :class:`~._model.PoseCost`'s kernels with (and ``PoseCost(backend="numpy")``).
Points in mm in the transducer frame, poses 4x4 ``T_carm_transducer``, distances in pixels.
"""

from __future__ import annotations

import numpy as np

__all__ = []

#: Points per chunk of the numpy reference (bounds its temporaries to a few MB).
NUMPY_CHUNK_POINTS = 1 << 15


def reference_distances(T: np.ndarray, P3: np.ndarray, p4: np.ndarray, dmap: np.ndarray, pts: np.ndarray,
                        outside_px: float, cap_px: float, jacobian: bool = False):
    """Interpolated distances ``d`` (px) of ``pts`` posed at ``T`` in the map ``dmap`` (``outside_px``
    where a point projects off the map or behind the source; every map value capped at ``cap_px``)
    and, with ``jacobian``, ``dd/d[w, v]`` (n, 6)."""
    rows, cols = dmap.shape
    q = pts @ T[:3, :3].T
    uvw = (q + T[:3, 3]) @ P3.T + p4
    hw = uvw[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = uvw[:, 0] / hw, uvw[:, 1] / hw
    inside = (hw > 0) & (u >= -0.5) & (u < cols - 0.5) & (v >= -0.5) & (v < rows - 0.5)
    d = np.full(len(pts), outside_px)
    ui, vi = u[inside], v[inside]
    uc = np.clip(ui, 0.0, cols - 1.0)
    vc = np.clip(vi, 0.0, rows - 1.0)
    x0 = np.minimum(uc.astype(np.int64), cols - 2)
    y0 = np.minimum(vc.astype(np.int64), rows - 2)
    fx, fy = uc - x0, vc - y0
    d00 = np.minimum(dmap[y0, x0].astype(np.float64), cap_px)
    d10 = np.minimum(dmap[y0, x0 + 1].astype(np.float64), cap_px)
    d01 = np.minimum(dmap[y0 + 1, x0].astype(np.float64), cap_px)
    d11 = np.minimum(dmap[y0 + 1, x0 + 1].astype(np.float64), cap_px)
    top = d00 + fx * (d10 - d00)
    bottom = d01 + fx * (d11 - d01)
    d[inside] = top + fy * (bottom - top)
    if not jacobian:
        return d
    gu = np.where(ui == uc, (1 - fy) * (d10 - d00) + fy * (d11 - d01), 0.0)
    gv = np.where(vi == vc, bottom - top, 0.0)
    g = ((gu[:, None] * (P3[0] - ui[:, None] * P3[2]) + gv[:, None] * (P3[1] - vi[:, None] * P3[2]))
         / hw[inside, None])
    J = np.zeros((len(pts), 6))
    J[inside, :3] = np.cross(q[inside], g)
    J[inside, 3:] = g
    return d, J


def reference_sum_of_squares(T: np.ndarray, P3: np.ndarray, p4: np.ndarray, dmap: np.ndarray, pts: np.ndarray,
                             outside_px: float, cap_px: float) -> float:
    """``sum_i d_i²`` (px²) of :func:`reference_distances`, in chunks of :data:`NUMPY_CHUNK_POINTS`."""
    total = 0.0
    for start in range(0, len(pts), NUMPY_CHUNK_POINTS):
        d = reference_distances(T, P3, p4, dmap, pts[start:start + NUMPY_CHUNK_POINTS], outside_px, cap_px)
        total += float(np.dot(d, d))
    return total
