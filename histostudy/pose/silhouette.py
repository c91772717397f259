"""The silhouette seed of the robust initialisation (beyond the paper; a start for §II-B.4's grid
search): a translation (mm, C-arm frame) at which the model's projected occupancy has the
segmented occupancy's centroid in every view, and the axial angles that fit the silhouettes best.
Occupancy grids are in cells of :data:`SILHOUETTE_CELL_PX` detector pixels.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numba
import numpy as np

from histostudy.imaging import View

from .init import rotation_from_direction

__all__ = ["SILHOUETTE_CELL_PX", "segmented_occupancy", "silhouette_candidates", "silhouette_seed"]

#: Cell side (detector pixels) of the occupancy grids :func:`silhouette_seed` compares: coarse
#: enough that a few thousand model points fill the projected silhouette, fine enough (about
#: 5 mm at the detector) for a seed that the 1 cm medium grid takes on.
SILHOUETTE_CELL_PX = 16


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _project_to_cells(uvw: np.ndarray, rows: int, cols: int, cell_px: int, grid_shape: tuple) -> tuple:
    """The cells of a ``grid_shape`` grid that the homogeneous image points ``uvw`` (``(n, 3)``,
    in front of the source and on a ``rows x cols`` detector) fall in, and which points those are:
    ``(occupied uint8 grid, visible mask)``. The arithmetic is numpy's, operation for operation
    (divide by ``w``, compare with the detector's edges, ``floor((u + 0.5) / cell_px)``), so the
    cells are the same bit for bit; one pass instead of a dozen temporaries."""
    occupied = np.zeros(grid_shape, np.uint8)
    visible = np.zeros(uvw.shape[0], np.bool_)
    u_end, v_end = cols - 0.5, rows - 0.5
    for i in range(uvw.shape[0]):
        w = uvw[i, 2]
        if not w > 0:
            continue
        u, v = uvw[i, 0] / w, uvw[i, 1] / w
        if u >= -0.5 and u < u_end and v >= -0.5 and v < v_end:
            visible[i] = True
            occupied[int(np.floor((v + 0.5) / cell_px)), int(np.floor((u + 0.5) / cell_px))] = 1
    return occupied, visible


def _occupancy_centroid(occupied: np.ndarray, cell_px: int) -> np.ndarray | None:
    rows, cols = np.nonzero(occupied)
    if rows.size == 0:
        return None
    return (np.array([cols.mean(), rows.mean()]) + 0.5) * cell_px - 0.5


def segmented_occupancy(views: Sequence[View], masks: Sequence[np.ndarray], cell_px: int = SILHOUETTE_CELL_PX
                        ) -> list[np.ndarray]:
    """Per view, the boolean grid of ``cell_px`` cells at least half covered by the mask."""
    grids = []
    for view, mask in zip(views, masks):
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != tuple(view.shape):
            raise ValueError(f"mask shape {mask.shape} does not match its view's detector {tuple(view.shape)}")
        shape = (-(-mask.shape[0] // cell_px), -(-mask.shape[1] // cell_px))
        padded = np.zeros((shape[0] * cell_px, shape[1] * cell_px), np.float32)
        padded[:mask.shape[0], :mask.shape[1]] = mask
        grids.append(padded.reshape(shape[0], cell_px, shape[1], cell_px).mean(axis=(1, 3)) >= 0.5)
    return grids


def silhouette_seed(R: np.ndarray, views: Sequence[View], masks: Sequence[np.ndarray], points_mm: np.ndarray,
                    *, centre_local_mm, cell_px: int = SILHOUETTE_CELL_PX, max_iter: int = 12,
                    tol_mm: float = 0.5,
                    occupancy: Sequence[np.ndarray] | None = None) -> tuple[np.ndarray, float] | None:
    """A translation of ``T_carm_transducer`` whose projected silhouettes have the segmented
    silhouettes' centroids in every view (beyond the paper; a seed for the grid search).

    The segmented transducer (every labelled pixel, ``masks``) and the model's projection at
    rotation ``R`` are both reduced to occupancy grids of ``cell_px`` cells clipped to the
    detector, so that the part of the transducer outside a view is left out of both centroids
    alike: the visible part's centroid, not the whole transducer's, is what the data show when
    half of it is off the detector — where the coarse grid's scores are nearly flat and its
    optimum can lie centimetres off (notebook 04's robustness sweep). Starting from the
    intersection of the rays through the segmented centroids (the model's ``centre_local_mm``
    placed there), the translation is corrected by Gauss-Newton on the centroid differences (px),
    with the projection's Jacobian at the visible part's centre, until a step is below
    ``tol_mm``.

    Args:
        R: 3x3 rotation of the transducer (the orientation stage's direction and an axial angle).
        views: two or more views (one view does not fix the depth).
        masks: per view, a boolean image of the segmented transducer.
        points_mm: ``(n, 3)`` model points in the transducer frame (a few thousand suffice).
        centre_local_mm: a point of the transducer frame near the middle of its silhouette.
        occupancy: the masks' occupancy grids from :func:`segmented_occupancy`, when already made
            (:func:`silhouette_candidates` makes them once for all its axial angles).

    Returns:
        ``(translation_mm, iou)``: the translation (C-arm frame) and the lowest over views of the
        intersection over union of the model's and the segmented occupancy grids there; None
        where a view shows nothing or the iteration leaves the views.
    """
    views = list(views)
    if len(views) < 2 or len(masks) != len(views):
        raise ValueError(f"silhouette_seed needs two or more views and one mask per view, got {len(views)} views "
                         f"and {len(masks)} masks")
    targets: list[np.ndarray] = []
    grids: list[tuple[int, ...]] = []
    closing = np.ones((3, 3), np.uint8)
    pts = np.asarray(points_mm, dtype=np.float64) @ R.T

    def model_occupancy(view, shape, t):
        world = pts + t
        rows, cols = view.shape
        occupied, visible = _project_to_cells(view.project_homogeneous(world), rows, cols, cell_px, shape)
        if visible.any():
            occupied = cv2.morphologyEx(occupied, cv2.MORPH_CLOSE, closing)
        return occupied > 0, world[visible]

    def silhouette_iou(t):
        ious = []
        for view, shape, seg in zip(views, grids, segmented):
            occ, _ = model_occupancy(view, shape, t)
            union = np.count_nonzero(occ | seg)
            ious.append(np.count_nonzero(occ & seg) / union if union else 0.0)
        return float(min(ious))

    segmented = segmented_occupancy(views, masks, cell_px) if occupancy is None else list(occupancy)
    for grid in segmented:
        centroid = _occupancy_centroid(grid, cell_px)
        if centroid is None:
            return None
        targets.append(centroid)
        grids.append(grid.shape)
    origins = np.array([v.source_mm for v in views])
    rays = np.vstack([v.ray_directions(c) for v, c in zip(views, targets)])
    # Least-squares intersection of the rays: sum_i (I - d_i d_i^T)(x - o_i) = 0.
    A = sum(np.eye(3) - np.outer(d, d) for d in rays)
    b = sum((np.eye(3) - np.outer(d, d)) @ o for d, o in zip(rays, origins))
    t = np.linalg.solve(A, b) - R @ np.asarray(centre_local_mm, dtype=np.float64)
    for _ in range(max_iter):
        residuals, jacobians = [], []
        for view, target, shape in zip(views, targets, grids):
            occupied, visible = model_occupancy(view, shape, t)
            if not len(visible):
                continue
            centroid = _occupancy_centroid(occupied, cell_px)
            anchor = visible.mean(axis=0)
            J = np.empty((2, 3))
            for k in range(3):
                step = np.zeros(3)
                step[k] = 1.0
                J[:, k] = view.project(anchor + step)[0] - view.project(anchor)[0]
            residuals.append(target - centroid)
            jacobians.append(J)
        if len(residuals) < 2:
            return None
        delta, *_ = np.linalg.lstsq(np.vstack(jacobians), np.concatenate(residuals), rcond=None)
        norm = float(np.linalg.norm(delta))
        if norm > 50.0:
            delta *= 50.0 / norm
        t = t + delta
        if norm < tol_mm:
            break
    return t, silhouette_iou(t)


def silhouette_candidates(direction, views: Sequence[View], masks: Sequence[np.ndarray], points_mm: np.ndarray, *,
                          centre_local_mm, axial_step_deg: float = 15.0, keep: int = 2,
                          cell_px: int = SILHOUETTE_CELL_PX) -> list[tuple[float, np.ndarray, float]]:
    """The ``keep`` axial angles (over ``[0, 180)`` deg, ``axial_step_deg`` apart) whose
    :func:`silhouette_seed` fits the segmented silhouettes best, as ``(axial_deg, translation_mm,
    iou)``, best first.

    The axial angle decides which part of the elliptical aperture lies off a detector: at 20 deg
    from the true angle the seed lands 2-5 cm off, at the best-fitting angle within about 1 cm,
    and the silhouettes' overlap singles that angle out (measured on notebook 04's robustness
    failures: IoU 0.87-0.96 at the true angle, below 0.75 beyond 15 deg from it).
    """
    if not (np.isfinite(axial_step_deg) and 0 < axial_step_deg <= 180):
        raise ValueError(f"axial_step_deg must be in (0, 180], got {axial_step_deg!r}")
    found = []
    occupancy = segmented_occupancy(views, masks, cell_px)
    for angle in np.arange(0.0, 180.0 - 1e-9, axial_step_deg):
        seeded = silhouette_seed(rotation_from_direction(direction, np.deg2rad(angle)), views, masks, points_mm,
                                 centre_local_mm=centre_local_mm, cell_px=cell_px, occupancy=occupancy)
        if seeded is not None:
            found.append((float(angle), seeded[0], seeded[1]))
    found.sort(key=lambda f: -f[2])
    return found[:max(1, keep)]
