"""The bubble clouds a treatment makes and what they leave (§II-D, §II-D.1, §IV): clouds at the reached
poses, the phantom's layers mixed there, and the post-treatment CBCT with the zone segmented in it (mm,
poses ``T_carm_transducer``, HU)."""

from __future__ import annotations

import numpy as np

from histostudy.geometry import check_rigid
from histostudy.imaging import Volume, check_mask, check_volume, phantom_mask, simulate_cbct, vector3_mm

from .zone import segment_treatment_zone

__all__ = [
    "BUBBLE_CLOUD_SIZE_MM",
    "bubble_cloud_mask",
    "post_treatment_phantom",
    "scan_treated_zone",
]

#: Full axes (LR, TB, depth) of the bubble cloud the paper's excitation sequence creates (§II-D), mm.
BUBBLE_CLOUD_SIZE_MM = (3.0, 3.0, 6.0)


def bubble_cloud_mask(
    volume: Volume,
    T_carm_transducer,
    focal_point_mm=(0.0, 0.0, 0.0),
    offset_mm=(0.0, 0.0, 0.0),
    size_mm=BUBBLE_CLOUD_SIZE_MM,
) -> np.ndarray:
    """Union of the bubble clouds at the given transducer poses, as a bool ``[z, y, x]`` mask.

    ``T_carm_transducer``: (4, 4) or (n, 4, 4) poses of the transducer frame in the C-arm frame
    (the reached poses, converted by the caller with the calibration's ground truth).
    ``focal_point_mm``: the physical transducer's true focal point in the transducer frame;
    ``offset_mm``: the bubble cloud's further offset from it (aberration, manufacturing, §IV),
    transducer frame. Each cloud is an ellipsoid of full axes ``size_mm`` (LR, TB, depth; paper:
    3x3x6 mm, §II-D) along the transducer's x, y, z, centred at ``focal_point_mm + offset_mm``.
    A voxel belongs to a cloud when its centre does.
    """
    volume = check_volume(volume)
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    if T.ndim == 2:
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"T_carm_transducer must be (4, 4) or (n, 4, 4), got shape {T.shape}")
    for k in range(len(T)):
        check_rigid(T[k], f"T_carm_transducer[{k}]")
    centre_tf = vector3_mm(focal_point_mm, "focal_point_mm") + vector3_mm(offset_mm, "offset_mm")
    semi = 0.5 * vector3_mm(size_mm, "size_mm", positive=True)
    mask = np.zeros(volume.data.shape, dtype=bool)
    reach = float(semi.max())
    n_xyz = np.asarray(volume.shape_xyz)
    x_ax, y_ax, z_ax = volume.axes_mm()
    for k in range(len(T)):
        c = T[k, :3, :3] @ centre_tf + T[k, :3, 3]
        lo = np.maximum(np.ceil((c - reach - volume.origin_mm) / volume.spacing_mm - 1e-9).astype(int), 0)
        hi = np.minimum(np.floor((c + reach - volume.origin_mm) / volume.spacing_mm + 1e-9).astype(int), n_xyz - 1)
        if np.any(hi < lo):
            continue  # this cloud lies outside the volume
        Z, Y, X = np.meshgrid(z_ax[lo[2] : hi[2] + 1], y_ax[lo[1] : hi[1] + 1], x_ax[lo[0] : hi[0] + 1], indexing="ij")
        d = np.stack([X - c[0], Y - c[1], Z - c[2]], axis=-1) @ T[k, :3, :3]  # transducer-frame offsets
        inside = np.sum((d / semi) ** 2, axis=-1) <= 1.0
        mask[lo[2] : hi[2] + 1, lo[1] : hi[1] + 1, lo[0] : hi[0] + 1] |= inside
    return mask


def post_treatment_phantom(phantom: Volume, treated_mask, roi_mask) -> Volume:
    """The phantom after treatment (§II-D.1): inside the treated part of the phantom the layers are
    mixed, so every voxel there takes the mean attenuation of that part of the untreated phantom.

    ``phantom``: the true (noise-free) pre-treatment attenuation, e.g.
    :func:`histostudy.imaging.cbct.phantom_volume`; ``treated_mask``: bool ``[z, y, x]``, e.g. the union
    of bubble clouds (:func:`bubble_cloud_mask`); ``roi_mask``: bool ``[z, y, x]``, the phantom
    (water around it is not mixed in). The mixture's mean weights both materials by their volume
    in the treated region. Pass the result to :func:`histostudy.imaging.cbct.simulate_cbct`.
    """
    phantom = check_volume(phantom, "phantom")
    treated = check_mask(treated_mask, phantom, "treated_mask")
    roi = check_mask(roi_mask, phantom, "roi_mask")
    region = treated & roi
    data = phantom.data.astype(np.float64).copy()
    if region.any():
        data[region] = data[region].mean()
    return phantom.with_data(data)


def scan_treated_zone(phantom: Volume, roi_mask, T_carm_transducer_reached, focal_point_mm, bubble_offset_mm, *,
                      spec, T_carm_phantom, rng: np.random.Generator, blur_sigma_mm: float, noise_sd_hu: float,
                      voxel_mm: float):
    """The post-treatment CBCT of a treatment and its segmented zone (§II-D.1, §II-E.3).

    The chain every study runs after a treatment: bubble clouds at the reached poses
    (:func:`bubble_cloud_mask`), the layers mixed there (:func:`post_treatment_phantom` inside
    ``roi_mask``), the CBCT simulated (:func:`histostudy.imaging.cbct.simulate_cbct`) and the zone
    segmented inside the phantom (:func:`histostudy.treatment.zone.segment_treatment_zone`).

    Args:
        phantom: the true phantom volume (HU, mm).
        roi_mask: bool ``[z, y, x]`` of ``phantom``'s shape, where the layers may mix.
        T_carm_transducer_reached: ``(n, 4, 4)`` reached poses, transducer -> C-arm, mm.
        focal_point_mm: the physical transducer's focal point in its frame, mm.
        bubble_offset_mm: the cloud's offset from the focal point in the transducer frame, mm.
        spec: the :class:`~histostudy.imaging.cbct.PhantomSpec`.
        T_carm_phantom: (4, 4) rigid, phantom -> C-arm, mm.
        rng: the Generator of the CBCT's noise.
        blur_sigma_mm: the CBCT's PSF, mm.
        noise_sd_hu: its noise, HU.
        voxel_mm: its voxel size, mm.

    Returns:
        ``(ZoneSegmentation, post-treatment CBCT Volume)``.

    Raises:
        TypeError: a volume or ``rng`` of the wrong type.
        ValueError: an argument out of range, or no zone found.
    """
    treated = bubble_cloud_mask(phantom, T_carm_transducer_reached, focal_point_mm, bubble_offset_mm)
    post = simulate_cbct(post_treatment_phantom(phantom, treated, roi_mask), rng, blur_sigma_mm=blur_sigma_mm,
                         noise_sd_hu=noise_sd_hu, voxel_mm=voxel_mm)
    return segment_treatment_zone(post, phantom_mask(post, spec, T_carm_phantom)), post
