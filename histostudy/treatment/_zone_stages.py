"""The stages of :func:`~histostudy.treatment.zone.segment_treatment_zone` (§II-E.3-4): local variance,
the phantom's interior, the homogeneous level, the coarse and the boundary stage. Arrays ``[z, y, x]``;
HU, HU^2, mm."""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from histostudy.imaging import Volume

__all__: list[str] = []


def _check_windows(window_mm: float, boundary_window_mm: float, smoothing_sigma_mm: float, n_refinements) -> None:
    """Raise ``ValueError`` naming the argument unless both windows (mm) are finite and > 0, the
    smoothing sigma (mm) finite and >= 0 and ``n_refinements`` an integer >= 0."""
    for name, value in (("window_mm", window_mm), ("boundary_window_mm", boundary_window_mm)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0 (about one layer period / one layer), got {value!r}")
    if not (math.isfinite(smoothing_sigma_mm) and smoothing_sigma_mm >= 0):
        raise ValueError(f"smoothing_sigma_mm must be finite and >= 0, got {smoothing_sigma_mm!r}")
    if isinstance(n_refinements, bool) or not isinstance(n_refinements, (int, np.integer)) or n_refinements < 0:
        raise ValueError(f"n_refinements must be an integer >= 0, got {n_refinements!r}")


def _odd_box(length_mm: float, spacing_zyx: np.ndarray) -> np.ndarray:
    """Box size in voxels per array axis, odd (so that the box is centred), about ``length_mm``."""
    return np.maximum(1, 2 * np.round(0.5 * length_mm / spacing_zyx).astype(int) + 1)


def _largest_component(candidates: np.ndarray, what: str) -> np.ndarray:
    """The largest 6-connected component of ``candidates`` with its holes filled."""
    labels, n = ndimage.label(candidates)
    if n == 0:
        raise ValueError(f"no treated (homogeneous) zone found inside the phantom ({what})")
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    return ndimage.binary_fill_holes(labels == int(np.argmax(counts)))


def _boundary_window_fraction(mask: np.ndarray, size: np.ndarray) -> float:
    """Mean fraction of a ``size`` box that ``mask`` fills, taken on the voxels either side of its
    boundary: the box filter's level on the mask's own surface (1/2 on a flat one, less on a
    convex one)."""
    box = ndimage.uniform_filter(mask.astype(np.float64), size=size, mode="nearest")
    inner = mask & ~ndimage.binary_erosion(mask)
    outer = ndimage.binary_dilation(mask) & ~mask
    return 0.5 * (float(box[inner].mean()) + float(box[outer].mean()))


def _local_variance(volume: Volume, window_mm: float,
                    smoothing_sigma_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(data, size, var)``: the CBCT's gray values (HU, float64, Gaussian-smoothed by
    ``smoothing_sigma_mm`` when > 0), the window's box size (voxels, about ``window_mm``) and the
    local variance (HU^2) over that box, clipped at 0."""
    sp_zyx = volume.spacing_mm[::-1]
    data = volume.data.astype(np.float64)
    if smoothing_sigma_mm > 0:
        data = ndimage.gaussian_filter(data, sigma=smoothing_sigma_mm / sp_zyx, mode="nearest")
    size = _odd_box(window_mm, sp_zyx)
    mean = ndimage.uniform_filter(data, size=size, mode="nearest")
    var = np.maximum(ndimage.uniform_filter(data * data, size=size, mode="nearest") - mean * mean, 0.0)
    return data, size, var


def _phantom_interior(roi: np.ndarray, size: np.ndarray, window_mm: float) -> np.ndarray:
    """The phantom ``roi`` eroded by half a window (box ``size``, voxels), away from its faces
    where the water/phantom step dominates the local variance; ``ValueError`` when under 10 voxels
    are left."""
    # (Box erosions/dilations as separable min/max filters: fast for large windows.)
    interior = ~ndimage.maximum_filter(~roi, size=size, mode="constant", cval=True)
    if interior.sum() < 10:
        raise ValueError(
            f"roi_mask leaves {int(interior.sum())} voxels once eroded by half of window_mm={window_mm}: "
            "the phantom region is too small for the segmentation window"
        )
    return interior


def _homogeneous_variance(var: np.ndarray, roi: np.ndarray, size: np.ndarray, noise_variance) -> float:
    """``v_h``, the local variance (HU^2) of homogeneous material: ``noise_variance`` if given,
    else the median over the water at least a whole window (box ``size``) from the phantom."""
    if noise_variance is not None:
        if not (math.isfinite(noise_variance) and noise_variance >= 0):
            raise ValueError(f"noise_variance must be finite and >= 0 (HU^2), got {noise_variance!r}")
        return float(noise_variance)
    # Water at least a whole window from the phantom, so that neither the window nor the
    # scanner's blur of the phantom's faces reaches into what is measured as pure noise.
    water = ~ndimage.maximum_filter(roi, size=2 * size + 1, mode="nearest")
    if water.sum() < 100:
        raise ValueError(
            f"the volume holds only {int(water.sum())} water voxels a window away from roi_mask, too few "
            "to measure the homogeneous (noise) variance: give a volume with water around the phantom "
            "or pass noise_variance"
        )
    return float(np.median(var[water]))


def _variance_zone(var: np.ndarray, interior: np.ndarray, v_l: float, v_h: float) -> np.ndarray:
    """The largest component of the interior voxels whose local variance lies below the midpoint
    of the layered ``v_l`` and the homogeneous ``v_h`` (HU^2); ``ValueError`` unless ``v_l > v_h``."""
    if not v_l > v_h:
        raise ValueError(
            f"no layer texture: the phantom's local variance ({v_l:.3g} HU^2) does not exceed that of "
            f"homogeneous material ({v_h:.3g} HU^2)"
        )
    return _largest_component((var < 0.5 * (v_l + v_h)) & interior, "local variance")


def _untreated_phantom(interior: np.ndarray, mask: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The interior without the zone ``mask`` grown by a window (box ``size``) plus a voxel for
    the scanner's blur: untreated phantom."""
    return interior & ~ndimage.maximum_filter(mask, size=size + 2, mode="constant", cval=False)


def _coarse_stage(var: np.ndarray, interior: np.ndarray, size: np.ndarray,
                  v_h: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The coarse stage, where is the zone: ``(mask, untreated, v_l)``, the low-variance zone, the
    untreated phantom around it and the layered phantom's local variance ``v_l`` (HU^2)."""
    # Two passes: the median over the whole interior is pulled down by the zone and by the shell
    # where windows straddle its boundary; the second pass takes the median over the interior
    # without the first zone grown by a window (+ a voxel for blur), i.e. over untreated phantom.
    mask = _variance_zone(var, interior, float(np.median(var[interior])), v_h)
    untreated = _untreated_phantom(interior, mask, size)
    if untreated.sum() >= 0.1 * interior.sum():
        v_l = float(np.median(var[untreated]))
        mask = _variance_zone(var, interior, v_l, v_h)
        untreated = _untreated_phantom(interior, mask, size)
    else:  # the zone leaves too little untreated phantom to measure: keep the first pass
        v_l = float(np.median(var[interior]))
    return mask, untreated, v_l


def _zone_core(mask: np.ndarray, untreated: np.ndarray, small: np.ndarray, boundary_window_mm: float) -> np.ndarray:
    """The coarse zone eroded by a boundary window (box ``small``): mixed material only;
    ``ValueError`` when it or the untreated phantom holds under 10 voxels."""
    core = ~ndimage.maximum_filter(~mask, size=small, mode="constant", cval=True)
    if core.sum() < 10 or untreated.sum() < 10:
        raise ValueError(
            f"the coarse zone ({int(mask.sum())} voxels) leaves {int(core.sum())} voxels once eroded by "
            f"boundary_window_mm={boundary_window_mm} and {int(untreated.sum())} untreated phantom voxels: "
            "too few to measure the boundary stage's levels"
        )
    return core


def _deviation_levels(data: np.ndarray, core: np.ndarray, untreated: np.ndarray,
                      small: np.ndarray) -> tuple[float, np.ndarray, float, float]:
    """``(mu, deviation, e_l, e_h)``: the mixed level ``mu`` (HU, median of the core), the local
    mean (box ``small``) of each voxel's deviation from it in units of its layer material's own
    distance from it, and that deviation's median in untreated phantom (``e_l``) and in the core
    (``e_h``); ``ValueError`` when a material or the texture is missing."""
    mu = float(np.median(data[core]))
    # Each material's own distance from the mixed level: a zone that cut the layers unevenly
    # mixes to a level nearer one of them, and the raw deviation would then see the boundary
    # earlier in a layer of the other material.
    low, high = data[untreated & (data < mu)], data[untreated & (data >= mu)]
    if len(low) < 10 or len(high) < 10:
        raise ValueError(
            f"the untreated phantom does not hold both layer materials on either side of the zone's level "
            f"({mu:.4g} HU): {len(low)} voxels below, {len(high)} above"
        )
    low_level, high_level = float(np.median(low)), float(np.median(high))
    untreated_fraction = np.where(data < mu, (mu - data) / (mu - low_level), (data - mu) / (high_level - mu))
    deviation = ndimage.uniform_filter(untreated_fraction, size=small, mode="nearest")
    e_l, e_h = float(np.median(deviation[untreated])), float(np.median(deviation[core]))
    if not e_l > e_h:
        raise ValueError(
            f"no layer texture around the zone: the phantom's mean deviation from the zone's level "
            f"({e_l:.3g}, in units of each material's distance from it) does not exceed the zone's own ({e_h:.3g})"
        )
    return mu, deviation, e_l, e_h


def _refine_boundary(deviation: np.ndarray, e_l: float, e_h: float, roi: np.ndarray, mask: np.ndarray,
                     small: np.ndarray, n_refinements: int) -> tuple[np.ndarray, float]:
    """``(mask, treated_fraction)``: the zone where the window's treated fraction exceeds the
    fraction the box filter (``small``) of the zone itself takes on its surface, found in
    ``n_refinements`` passes from 1/2 (the self-consistent threshold), inside the phantom."""
    inside_phantom = ~ndimage.maximum_filter(~roi, size=small, mode="constant", cval=True)
    treated_fraction = 0.5
    for step in range(n_refinements + 1):
        if step:
            treated_fraction = _boundary_window_fraction(mask, small)
        mask = _largest_component((deviation < e_h + (1.0 - treated_fraction) * (e_l - e_h)) & inside_phantom,
                                  "deviation from the zone's level")
    return mask, treated_fraction


def _boundary_stage(volume: Volume, data: np.ndarray, roi: np.ndarray, mask: np.ndarray, untreated: np.ndarray,
                    boundary_window_mm: float, n_refinements: int) -> tuple[np.ndarray, float, float, float, float]:
    """The boundary stage, where exactly does the zone end: ``(mask, mu, e_l, e_h,
    treated_fraction)`` from the coarse ``mask`` and the untreated phantom, on a box of about
    ``boundary_window_mm``."""
    small = _odd_box(boundary_window_mm, volume.spacing_mm[::-1])
    core = _zone_core(mask, untreated, small, boundary_window_mm)
    mu, deviation, e_l, e_h = _deviation_levels(data, core, untreated, small)
    mask, treated_fraction = _refine_boundary(deviation, e_l, e_h, roi, mask, small, n_refinements)
    return mask, mu, e_l, e_h, treated_fraction
