"""The layered agarose-barium phantom and its simulated cone-beam CT (§II-D.1, §II-D): the phantom
rasterised, the scanner simulated (blur, resampling, noise), and targets drawn or checked inside it.
Volumes in the world frame, mm, HU (docs/imaging.md, "The phantom")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from histostudy.core import as_generator
from histostudy.geometry import as_points, check_rigid, invert_transform, transform_points

from .volume import Volume, check_volume, vector3_mm

__all__ = [
    "PhantomSpec",
    "check_target",
    "phantom_mask",
    "phantom_values",
    "phantom_volume",
    "random_target",
    "simulate_cbct",
]


@dataclass(frozen=True)
class PhantomSpec:
    """The layered agarose / agarose-barium phantom of §II-D.1, in water.

    Phantom frame: origin at the cube centre, axes along the cube edges, layers stacked along +z from
    the bottom face (z = -size/2), alternating. The gray values are assumptions of this study (the
    paper gives recipes, not CT numbers); the 420 HU between layers is what makes the mixed zone
    visible (a medium value, ~240 HU, without layer texture). See docs/imaging.md, "The phantom".

    Args:
        size_mm: the cube's edge in mm (paper: a 5x5x5 cm mold).
        layer_thickness_mm: each layer's thickness in mm (paper: "approximately 4 mm"); at most
            ``size_mm``.
        first_layer: ``"agarose"`` or ``"barium"``, the bottom layer.
        water_hu: the saline bath, HU (0 by the definition of the scale).
        agarose_hu: 1.5 % agarose in saline with 5 % red blood cells, HU.
        barium_hu: the same with ~2.4 % w/v BaSO4, HU.

    Raises:
        ValueError: a size not finite and > 0, a layer thicker than the cube, an unknown
            ``first_layer``, or a gray value not finite.
    """

    size_mm: float = 50.0
    layer_thickness_mm: float = 4.0
    first_layer: str = "agarose"
    water_hu: float = 0.0
    agarose_hu: float = 30.0
    barium_hu: float = 450.0

    def __post_init__(self):
        for name in ("size_mm", "layer_thickness_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0 (mm), got {v!r}")
        if self.layer_thickness_mm > self.size_mm:
            raise ValueError(
                f"layer_thickness_mm must not exceed size_mm={self.size_mm}, got {self.layer_thickness_mm!r}"
            )
        if self.first_layer not in ("agarose", "barium"):
            raise ValueError(f"first_layer must be 'agarose' or 'barium', got {self.first_layer!r}")
        for name in ("water_hu", "agarose_hu", "barium_hu"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number (HU), got {v!r}")

    @property
    def layer_contrast_hu(self) -> float:
        """``|barium_hu - agarose_hu|``: the layer contrast the segmentation relies on."""
        return abs(self.barium_hu - self.agarose_hu)

    @property
    def n_layers(self) -> int:
        return int(math.ceil(self.size_mm / self.layer_thickness_mm - 1e-9))

    def layer_index(self, z_phantom_mm) -> np.ndarray:
        """Layer number (0 = bottom) of phantom-frame heights ``z`` (mm)."""
        z = np.asarray(z_phantom_mm, dtype=np.float64)
        idx = np.floor((z + 0.5 * self.size_mm) / self.layer_thickness_mm).astype(int)
        return np.clip(idx, 0, self.n_layers - 1)

    def layer_values(self, z_phantom_mm) -> np.ndarray:
        """HU of the layer at phantom-frame heights ``z`` (mm), ignoring the cube's extent."""
        idx = self.layer_index(z_phantom_mm)
        first, second = ((self.agarose_hu, self.barium_hu) if self.first_layer == "agarose"
                         else (self.barium_hu, self.agarose_hu))
        return np.where(idx % 2 == 0, first, second)

    def contains_local(self, points_phantom_mm, margin_mm: float = 0.0) -> np.ndarray:
        """Whether phantom-frame points lie inside the cube shrunk by ``margin_mm`` on every face."""
        p = as_points(points_phantom_mm)
        return np.all(np.abs(p) <= 0.5 * self.size_mm - margin_mm, axis=1)


def _check_T(T_carm_phantom) -> np.ndarray:
    if T_carm_phantom is None:
        return np.eye(4)
    return check_rigid(T_carm_phantom, "T_carm_phantom")


def phantom_values(points_mm, spec: PhantomSpec = PhantomSpec(), T_carm_phantom=None) -> np.ndarray:
    """HU of the phantom set-up (layered cube in water) at world points ``(n, 3)`` mm (§II-D.1).

    ``T_carm_phantom`` places the phantom frame (cube centre, layers along its +z) in the C-arm
    frame (default: identity, the cube centred on the isocentre with horizontal layers).
    """
    T = _check_T(T_carm_phantom)
    local = transform_points(invert_transform(T), points_mm)
    inside = spec.contains_local(local)
    return np.where(inside, spec.layer_values(local[:, 2]), spec.water_hu)


def phantom_volume(
    spec: PhantomSpec = PhantomSpec(),
    T_carm_phantom=None,
    *,
    spacing_mm=0.5,
    margin_mm: float = 12.0,
    supersample: int = 2,
) -> Volume:
    """The phantom set-up rasterised on a world-aligned grid: the "true" attenuation (§II-D.1).

    Each voxel is the mean of ``supersample**3`` sub-voxel samples, so that layer and cube edges get
    partial-volume values as a scanner's detector integration would give them.

    Args:
        spec: the phantom.
        T_carm_phantom: (4, 4) rigid transform phantom -> C-arm (mm); None for the identity.
        spacing_mm: voxel size in mm, scalar or ``(3,)``, > 0.
        margin_mm: water around the phantom's bounding box on every side, mm, >= 0.
        supersample: sub-voxel samples per axis, an integer >= 1.

    Returns:
        A :class:`~.volume.Volume` of HU values.

    Raises:
        ValueError: ``margin_mm``, ``supersample``, ``spacing_mm`` or ``T_carm_phantom`` out of range.
    """
    T = _check_T(T_carm_phantom)
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be finite and >= 0, got {margin_mm!r}")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
    sp = vector3_mm(spacing_mm, "spacing_mm", positive=True)
    h = 0.5 * spec.size_mm
    corners = np.array([[sx, sy, sz] for sx in (-h, h) for sy in (-h, h) for sz in (-h, h)])
    world = transform_points(T, corners)
    lo = world.min(axis=0) - margin_mm
    hi = world.max(axis=0) + margin_mm
    vol = Volume.from_bounds(lo, hi, sp)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    first, second = ((spec.agarose_hu, spec.barium_hu) if spec.first_layer == "agarose"
                     else (spec.barium_hu, spec.agarose_hu))
    acc = np.zeros(vol.data.shape)
    for ox in offsets:
        for oy in offsets:
            for oz in offsets:
                lx, ly, lz = _grid_in_frame(vol, T, np.array([ox, oy, oz]) * sp)
                inside = (np.abs(lx) <= h) & (np.abs(ly) <= h) & (np.abs(lz) <= h)
                layer = spec.layer_index(lz)
                acc += np.where(inside, np.where(layer % 2 == 0, first, second), spec.water_hu)
    return vol.with_data(acc / supersample**3)


def _grid_in_frame(volume: Volume, T_world_frame: np.ndarray, offset_mm=(0.0, 0.0, 0.0)) -> list[np.ndarray]:
    """Coordinates (three ``[z, y, x]`` arrays) of the voxel centres (+ ``offset_mm``, world) in a frame.

    Separable in the grid axes, so it costs three array additions instead of an (n, 3) transform.
    """
    R, t = T_world_frame[:3, :3], T_world_frame[:3, 3]
    x, y, z = volume.axes_mm()
    x, y, z = x + offset_mm[0], y + offset_mm[1], z + offset_mm[2]
    local_t = R.T @ t
    return [
        R[0, a] * x[None, None, :] + R[1, a] * y[None, :, None] + R[2, a] * z[:, None, None] - local_t[a]
        for a in range(3)
    ]


def phantom_mask(volume: Volume, spec: PhantomSpec = PhantomSpec(), T_carm_phantom=None,
                 margin_mm: float = 0.0) -> np.ndarray:
    """The voxels of a volume whose centre lies in the phantom cube.

    Args:
        volume: the grid (world mm).
        spec: the phantom.
        T_carm_phantom: (4, 4) rigid transform phantom -> C-arm (mm); None for the identity.
        margin_mm: shrink the cube by this much on every face (mm; negative grows it).

    Returns:
        Boolean ``[z, y, x]`` mask of ``volume``'s shape.

    Raises:
        TypeError: ``volume`` is not a Volume.
        ValueError: ``T_carm_phantom`` is not rigid.
    """
    volume = check_volume(volume)
    T = _check_T(T_carm_phantom)
    h = 0.5 * spec.size_mm - margin_mm
    lx, ly, lz = _grid_in_frame(volume, T)
    return (np.abs(lx) <= h) & (np.abs(ly) <= h) & (np.abs(lz) <= h)


# ---------------------------------------------------------------------------------------------
# CBCT simulation
# ---------------------------------------------------------------------------------------------


def simulate_cbct(
    truth: Volume,
    rng,
    *,
    blur_sigma_mm: float = 0.5,
    noise_sd_hu: float = 20.0,
    voxel_mm=None,
) -> Volume:
    """A reconstructed CBCT of the true attenuation (the scanner stand-in, §II-D).

    The scanner's point-spread function is an isotropic Gaussian (``scipy.ndimage.gaussian_filter``);
    the volume is then resampled (trilinearly) over the same extent, and white Gaussian noise is added
    per voxel, a stand-in for reconstruction noise, whose real spectrum is not white (an assumption).

    Args:
        truth: the true attenuation, e.g. :func:`phantom_volume`'s (HU).
        rng: a ``numpy.random.Generator`` or an int seed.
        blur_sigma_mm: the PSF's standard deviation, mm, >= 0.
        noise_sd_hu: the noise's standard deviation, HU, >= 0.
        voxel_mm: the output voxel size, mm, scalar or ``(3,)``; None keeps ``truth``'s grid.

    Returns:
        The simulated CBCT, a :class:`~.volume.Volume` in HU.

    Raises:
        TypeError: ``truth`` is not a Volume, or ``rng`` is neither a Generator nor an int.
        ValueError: ``blur_sigma_mm`` or ``noise_sd_hu`` is not finite and >= 0, or ``voxel_mm`` is
            not > 0.
    """

    truth = check_volume(truth, "truth")
    gen = as_generator(rng)
    if not (math.isfinite(blur_sigma_mm) and blur_sigma_mm >= 0):
        raise ValueError(f"blur_sigma_mm must be finite and >= 0, got {blur_sigma_mm!r}")
    if not (math.isfinite(noise_sd_hu) and noise_sd_hu >= 0):
        raise ValueError(f"noise_sd_hu must be finite and >= 0, got {noise_sd_hu!r}")
    data = truth.data.astype(np.float64)
    if blur_sigma_mm > 0:
        sigma_vox = (blur_sigma_mm / truth.spacing_mm)[::-1]  # array order (z, y, x)
        data = ndimage.gaussian_filter(data, sigma=sigma_vox, mode="nearest")
    blurred = truth.with_data(data)
    if voxel_mm is None:
        out = blurred
    else:
        sp = vector3_mm(voxel_mm, "voxel_mm", positive=True)
        grid = Volume.from_bounds(truth.lower_mm, truth.upper_mm, sp)
        values = blurred.sample(grid.world_points().reshape(-1, 3), outside=0.0)
        out = grid.with_data(values.reshape(grid.data.shape))
    noisy = out.data.astype(np.float64)
    if noise_sd_hu > 0:
        noisy = noisy + gen.normal(0.0, noise_sd_hu, size=noisy.shape)
    return out.with_data(noisy)


# ---------------------------------------------------------------------------------------------
# Target and treatment zone (§II-D)
# ---------------------------------------------------------------------------------------------


def check_target(
    target_mm,
    spec: PhantomSpec = PhantomSpec(),
    T_carm_phantom=None,
    volume: Volume | None = None,
    margin_mm: float = 0.0,
) -> np.ndarray:
    """A target picked in the pre-treatment CBCT (§II-D), checked to lie in the phantom.

    Args:
        target_mm: world (C-arm) point ``(x, y, z)`` in mm.
        spec: the phantom.
        T_carm_phantom: (4, 4) rigid transform phantom -> C-arm (mm); None for the identity.
        volume: when given, the target must also lie inside this :class:`~.volume.Volume`'s voxel
            centres.
        margin_mm: how far inside the cube's faces the target must be (pass the zone radius to keep
            the whole zone in the phantom), >= 0.

    Returns:
        The target as a float64 ``(3,)`` array, mm.

    Raises:
        ValueError: ``target_mm`` is not 3 finite numbers, ``margin_mm`` is not finite and >= 0,
            ``T_carm_phantom`` is not rigid, or the target lies outside the volume or the shrunk
            cube (the message gives its value and the bound).
        TypeError: ``volume`` is not a Volume.
    """
    t = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"target_mm must be 3 finite numbers (world x, y, z in mm), got {target_mm!r}")
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be finite and >= 0, got {margin_mm!r}")
    T = _check_T(T_carm_phantom)
    if volume is not None:
        volume = check_volume(volume)
        if not volume.contains(t)[0]:
            raise ValueError(
                f"target_mm={t.round(3).tolist()} lies outside the CBCT volume "
                f"(voxel centres span {volume.lower_mm.round(3).tolist()} to {volume.upper_mm.round(3).tolist()} mm)"
            )
    local = transform_points(invert_transform(T), t)[0]
    if not spec.contains_local(local, margin_mm)[0]:
        raise ValueError(
            f"target_mm={t.round(3).tolist()} lies outside the phantom (phantom-frame position "
            f"{local.round(3).tolist()} mm; it must lie within +-{0.5 * spec.size_mm - margin_mm:.3f} mm "
            f"of the cube centre on each axis, i.e. {margin_mm} mm inside the {spec.size_mm} mm cube)"
        )
    return t


def random_target(rng, spec: PhantomSpec = PhantomSpec(), T_carm_phantom=None, border_mm: float = 15.0) -> np.ndarray:
    """A target drawn uniformly inside the phantom, away from its faces (§II-D).

    Args:
        rng: a ``numpy.random.Generator`` or an int seed.
        spec: the phantom.
        T_carm_phantom: (4, 4) rigid transform phantom -> C-arm (mm); None for the identity.
        border_mm: least distance from every face, mm; for the study, the zone radius plus a safety
            margin keeps the whole treatment zone (and the segmentation window) inside the phantom.

    Returns:
        The target, world (C-arm) ``(3,)`` float64, mm.

    Raises:
        ValueError: ``border_mm`` is not in ``[0, size_mm / 2]``, or ``T_carm_phantom`` is not rigid.
        TypeError: ``rng`` is neither a Generator nor an int.
    """

    gen = as_generator(rng)
    half = 0.5 * spec.size_mm - border_mm
    if not (math.isfinite(border_mm) and border_mm >= 0) or half < 0:
        raise ValueError(
            f"border_mm must be in [0, {0.5 * spec.size_mm}] mm for a {spec.size_mm} mm phantom, got {border_mm!r}"
        )
    local = gen.uniform(-half, half, size=3)
    return transform_points(_check_T(T_carm_phantom), local)[0]
