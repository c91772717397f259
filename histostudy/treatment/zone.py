"""The treatment zone (§II-D, §II-E.3-4): the prescribed sphere (world mm) and its automatic segmentation in
the post-treatment CBCT (docs/robot.md, "Segmenting the treated zone")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from histostudy.geometry import as_points, check_rotation, fit_sphere
from histostudy.imaging import Volume, check_mask, check_volume

from ._zone_stages import (
    _boundary_stage,
    _check_windows,
    _coarse_stage,
    _homogeneous_variance,
    _local_variance,
    _phantom_interior,
)

__all__ = ["PAPER_ZONE_DIAMETERS_MM", "TreatmentZone", "ZoneSegmentation", "segment_treatment_zone"]

#: Treatment sphere diameters of the paper's targeting studies (§II-D), mm.
PAPER_ZONE_DIAMETERS_MM = (20.0, 25.0)


@dataclass(frozen=True)
class TreatmentZone:
    """The prescribed spherical treatment zone (§II-D).

    Args:
        centre_mm: the zone's centre, world (C-arm) ``(x, y, z)``, mm.
        diameter_mm: its diameter, mm, > 0 (the paper's studies use 20 and 25 mm,
            :data:`PAPER_ZONE_DIAMETERS_MM`).

    Raises:
        ValueError: ``centre_mm`` not 3 finite numbers, or ``diameter_mm`` not a finite number > 0.
    """

    centre_mm: np.ndarray
    diameter_mm: float = 20.0

    def __post_init__(self):
        c = np.asarray(self.centre_mm, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"centre_mm must be 3 finite numbers (world mm), got {self.centre_mm!r}")
        object.__setattr__(self, "centre_mm", c)
        d = self.diameter_mm
        if (isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating))
                or not (math.isfinite(d) and d > 0)):
            raise ValueError(f"diameter_mm must be a finite number > 0 (paper: 20 or 25 mm), got {d!r}")
        object.__setattr__(self, "diameter_mm", float(d))

    @property
    def radius_mm(self) -> float:
        return 0.5 * self.diameter_mm

    def contains(self, points_mm) -> np.ndarray:
        """Whether world points lie in the closed ball, ``(n,)`` bool."""
        return np.linalg.norm(as_points(points_mm) - self.centre_mm, axis=1) <= self.radius_mm

    def mask(self, volume: Volume) -> np.ndarray:
        """Boolean ``[z, y, x]`` mask of the voxels whose centre lies in the zone."""
        volume = check_volume(volume)
        x, y, z = (a - c for a, c in zip(volume.axes_mm(), self.centre_mm))
        return x[None, None, :] ** 2 + y[None, :, None] ** 2 + z[:, None, None] ** 2 <= self.radius_mm**2

    def margin_points(self, axes=None) -> np.ndarray:
        """The six margin points ``centre +- r * axis`` (§II-D), ``(6, 3)`` world mm.

        ``axes``: 3x3 rotation whose columns are the directions (default: the world axes; pass
        ``T_carm_transducer[:3, :3]`` for LR, TB and -depth). Order: +a0, -a0, +a1, -a1, +a2, -a2.
        """
        R = np.eye(3) if axes is None else check_rotation(axes, "axes")
        out = []
        for a in range(3):
            out.append(self.centre_mm + self.radius_mm * R[:, a])
            out.append(self.centre_mm - self.radius_mm * R[:, a])
        return np.array(out)


# ---------------------------------------------------------------------------------------------
# Zone segmentation (§II-E.3-4)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ZoneSegmentation:
    """The treated (mixed) zone found in a post-treatment CBCT (§II-E.3-4), world mm; made by
    :func:`segment_treatment_zone`.

    Args:
        mask: bool ``[z, y, x]`` on the CBCT grid.
        centroid_mm: mean voxel-centre position of the mask (the paper's reference point), mm.
        sphere_centre_mm: centre of the least-squares sphere (:func:`histostudy.geometry.fit_sphere`)
            through the mask's boundary faces, mm.
        sphere_radius_mm: its radius, mm.
        equivalent_radius_mm: radius of the ball of the mask's volume, mm.
        volume_mm3: the mask's volume, mm^3.
        layered_variance: local variance of untreated phantom, HU^2 (the coarse stage).
        homogeneous_variance: local variance of homogeneous material, HU^2.
        threshold_variance: the threshold between the two, HU^2.
        spacing_mm: the CBCT's voxel size ``(dx, dy, dz)``, mm.
        origin_mm: the CBCT's origin (centre of voxel ``[0, 0, 0]``), mm.
        zone_level_hu: the mixed material's gray value, HU.
        layered_deviation: the local mean deviation from ``zone_level_hu`` in untreated phantom, in
            units of each layer material's own distance from it (1 on an untreated voxel, 0 on a mixed
            one).
        homogeneous_deviation: the same inside the zone.
        treated_fraction_threshold: the treated fraction of the boundary window at which the boundary
            was put (the boundary stage).
    """

    mask: np.ndarray
    centroid_mm: np.ndarray
    sphere_centre_mm: np.ndarray
    sphere_radius_mm: float
    equivalent_radius_mm: float
    volume_mm3: float
    layered_variance: float
    homogeneous_variance: float
    threshold_variance: float
    spacing_mm: np.ndarray
    origin_mm: np.ndarray
    zone_level_hu: float = float("nan")
    layered_deviation: float = float("nan")
    homogeneous_deviation: float = float("nan")
    treated_fraction_threshold: float = float("nan")

    def radii_along(self, axes) -> np.ndarray:
        """Radius of the zone along each column of ``axes`` (3x3 rotation), ``(3,)`` mm.

        Half the zone's extent along the line through the centroid: the mask is interpolated
        trilinearly and its 0.5 crossings found on either side (sub-voxel). With
        ``axes = T_carm_transducer[:3, :3]`` this gives the (LR, TB, depth) radii of §II-E.3.
        """
        R = check_rotation(axes, "axes")
        grid = Volume(self.mask.astype(np.float32), self.spacing_mm, self.origin_mm)
        step = 0.1 * float(self.spacing_mm.min())
        extent = float(np.linalg.norm((np.asarray(grid.shape_xyz) - 1) * self.spacing_mm))
        t = np.arange(0.0, extent + step, step)
        radii = []
        for a in range(3):
            ends = []
            for sign in (1.0, -1.0):
                pts = self.centroid_mm + sign * t[:, None] * R[:, a]
                f = grid.sample(pts, outside=0.0)
                below = np.nonzero(f < 0.5)[0]
                if len(below) == 0 or below[0] == 0:
                    ends.append(0.0)
                    continue
                i = below[0]  # first sample outside; interpolate the 0.5 crossing
                f0, f1 = f[i - 1], f[i]
                ends.append(t[i - 1] + (f0 - 0.5) / (f0 - f1) * step)
            radii.append(0.5 * (ends[0] + ends[1]))
        return np.array(radii)

    def distance_to_surface(self, points_mm, signed: bool = False) -> np.ndarray:
        """Distance (mm) of points to the fitted sphere's surface (§II-E.3 margin error).

        Unsigned by default; ``signed=True`` gives ``|p - c| - r`` (positive outside).
        """
        d = np.linalg.norm(as_points(points_mm) - self.sphere_centre_mm, axis=1) - self.sphere_radius_mm
        return d if signed else np.abs(d)


def _boundary_faces(mask: np.ndarray, volume: Volume) -> np.ndarray:
    """World midpoints of the faces between mask and non-mask voxels (6-neighbours), ``(n, 3)``."""
    pts = []
    for axis in range(3):  # array axis: 0 = z, 1 = y, 2 = x
        a = np.take(mask, range(mask.shape[axis] - 1), axis=axis)
        b = np.take(mask, range(1, mask.shape[axis]), axis=axis)
        idx = np.argwhere(a != b).astype(np.float64)
        idx[:, axis] += 0.5
        pts.append(idx)
    ijk = np.concatenate(pts)[:, ::-1]  # to (x, y, z) order
    return volume.voxel_to_world(ijk) if len(ijk) else np.zeros((0, 3))


def segment_treatment_zone(
    volume: Volume,
    roi_mask,
    *,
    window_mm: float = 8.0,
    boundary_window_mm: float = 4.0,
    smoothing_sigma_mm: float = 0.5,
    noise_variance: float | None = None,
    n_refinements: int = 2,
) -> ZoneSegmentation:
    """The mixed (treated) zone in a post-treatment CBCT of the layered phantom (§II-E.3-4).

    The automatic stand-in for the paper's manual annotation, in two stages: a coarse stage finds
    the zone by its low local variance over one layer period (``window_mm``), then a boundary stage
    puts its surface where the local deviation from the mixed material's gray value, averaged over
    ``boundary_window_mm``, says the window is treated by the fraction the box filter of the shape
    itself takes on its surface (``n_refinements`` passes). The method, its levels and its measured
    accuracy: docs/robot.md, "Segmenting the treated zone".

    Args:
        volume: the post-treatment CBCT (HU, mm); it needs about ``window_mm`` + a few mm of water
            around the phantom (:func:`~histostudy.imaging.cbct.phantom_volume`'s default margin gives
            it).
        roi_mask: bool ``[z, y, x]`` of ``volume``'s shape, the phantom (e.g.
            :func:`~histostudy.imaging.cbct.phantom_mask`).
        window_mm: the coarse stage's window, one layer period (8 mm = 2 x 4 mm layers), mm.
        boundary_window_mm: the boundary stage's box, about one layer, mm.
        smoothing_sigma_mm: Gaussian smoothing against noise first, mm.
        noise_variance: the homogeneous material's local variance, HU^2; None estimates it from the
            water outside ``roi_mask``.
        n_refinements: passes of the self-consistent boundary threshold, from 1/2.

    Returns:
        The :class:`ZoneSegmentation`.

    Raises:
        TypeError: ``volume`` is not a Volume.
        ValueError: ``roi_mask`` not a bool mask of the volume's shape, a window or count out of
            range, nothing found, or the levels cannot be estimated.
    """
    volume = check_volume(volume)
    roi = check_mask(roi_mask, volume, "roi_mask")
    _check_windows(window_mm, boundary_window_mm, smoothing_sigma_mm, n_refinements)
    data, size, var = _local_variance(volume, window_mm, smoothing_sigma_mm)
    interior = _phantom_interior(roi, size, window_mm)
    v_h = _homogeneous_variance(var, roi, size, noise_variance)
    mask, untreated, v_l = _coarse_stage(var, interior, size, v_h)
    mask, mu, e_l, e_h, treated_fraction = _boundary_stage(volume, data, roi, mask, untreated, boundary_window_mm,
                                                           n_refinements)
    return _measure_zone(mask, volume, v_l=v_l, v_h=v_h, mu=mu, e_l=e_l, e_h=e_h, treated_fraction=treated_fraction)


def _measure_zone(mask: np.ndarray, volume: Volume, *, v_l: float, v_h: float, mu: float, e_l: float, e_h: float,
                  treated_fraction: float) -> ZoneSegmentation:
    """The :class:`ZoneSegmentation` of the segmented ``mask`` (§II-E.3-4): its centroid (world
    mm, the paper's reference point), volume (mm^3), equivalent radius and least-squares sphere
    through its boundary faces (mm), with the levels the segmentation used (HU^2, HU, units of
    the layer materials' distance from the mixed level)."""
    idx = np.argwhere(mask)[:, ::-1].astype(np.float64)  # (x, y, z) voxel coordinates
    centroid = volume.voxel_to_world(idx.mean(axis=0))[0]
    vol_mm3 = float(len(idx)) * volume.voxel_volume_mm3
    faces = _boundary_faces(mask, volume)
    if len(faces) >= 4:
        c, r = fit_sphere(faces)
    else:
        c, r = centroid.copy(), float("nan")
    return ZoneSegmentation(
        mask=mask,
        centroid_mm=centroid,
        sphere_centre_mm=np.asarray(c, dtype=np.float64),
        sphere_radius_mm=float(r),
        equivalent_radius_mm=float((3.0 * vol_mm3 / (4.0 * math.pi)) ** (1.0 / 3.0)),
        volume_mm3=vol_mm3,
        layered_variance=v_l,
        homogeneous_variance=v_h,
        threshold_variance=0.5 * (v_l + v_h),
        spacing_mm=volume.spacing_mm.copy(),
        origin_mm=volume.origin_mm.copy(),
        zone_level_hu=mu,
        layered_deviation=e_l,
        homogeneous_deviation=e_h,
        treated_fraction_threshold=treated_fraction,
    )
