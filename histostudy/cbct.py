"""CBCT volumes, the layered agarose-barium phantom, the treatment zone and its segmentation.

Paper sections: §II-A (a CBCT is a voxel grid ``V`` whose value at a point between voxel centres
is the trilinear interpolation), §II-D.1 (the layered phantom: a 5x5x5 cm agarose cube of ~4 mm
alternating layers with and without barium, in water; histotripsy mixes the layers into a medium
attenuation), §II-D (a spherical target of 2.0 or 2.5 cm diameter picked in the pre-treatment
CBCT), §II-E.3-4 (the effective treatment zone segmented in the post-treatment CBCT: its centroid,
its radius along depth/TB/LR, and the distance of predicted margin points to its surface).

Frames and units: millimetres; the CBCT/C-arm frame is the world frame (origin at the isocentre).
A :class:`Volume` is axis-aligned with the world frame: ``data`` is indexed ``[iz, iy, ix]``
(z slowest), while ``spacing_mm``, ``origin_mm`` and every point or voxel coordinate are given in
``(x, y, z)`` order. ``origin_mm`` is the world position of the centre of voxel ``(0, 0, 0)``.
Gray values are in Hounsfield units (HU): water 0 HU.

Where the synthetic study stands in for the lab (docs/architecture.md, Synthetic stand-ins for
the lab): the physical phantom is the analytic :class:`PhantomSpec` rasterised by
:func:`phantom_volume`; the scanner is :func:`simulate_cbct` (Gaussian blur, resampling, Gaussian
noise); the manual annotation of the treated zone is the automatic :func:`segment_treatment_zone`
(local variance, then local deviation from the mixed level; see there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .geometry import as_points, check_rigid, check_rotation, fit_sphere, invert_transform, transform_points
from .seeding import as_generator

__all__ = [
    "PAPER_ZONE_DIAMETERS_MM",
    "PhantomSpec",
    "TreatmentZone",
    "Volume",
    "ZoneSegmentation",
    "check_target",
    "phantom_mask",
    "phantom_values",
    "phantom_volume",
    "random_target",
    "segment_treatment_zone",
    "simulate_cbct",
]

#: Treatment sphere diameters of the paper's targeting studies (§II-D), mm.
PAPER_ZONE_DIAMETERS_MM = (20.0, 25.0)


def _vec3(value, name: str, positive: bool = False) -> np.ndarray:
    """``value`` as a finite float64 (3,) vector (a scalar is broadcast); errors name ``name``."""
    if value is None:
        raise ValueError(f"{name} is required (3 numbers in mm, x, y, z order), got None")
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    arr = arr.reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be 3 finite numbers in mm (x, y, z order), got {value!r}")
    if positive and np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0 on every axis, got {arr.tolist()}")
    return arr


# ---------------------------------------------------------------------------------------------
# Volume
# ---------------------------------------------------------------------------------------------


@dataclass(eq=False)
class Volume:
    """A CBCT (or phantom) volume on an axis-aligned grid in the C-arm (world) frame (§II-A).

    ``data``: float32 array indexed ``[iz, iy, ix]``. ``spacing_mm``: voxel size ``(dx, dy, dz)``
    in mm, required and > 0 (a volume without spacing has no geometry and is refused).
    ``origin_mm``: world position ``(x, y, z)`` of the centre of voxel ``[0, 0, 0]``.
    Voxel coordinates ``(i, j, k)`` are continuous indices in ``(x, y, z)`` order:
    ``world = origin_mm + (i, j, k) * spacing_mm``.
    """

    data: np.ndarray
    spacing_mm: np.ndarray | None
    origin_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        data = np.asarray(self.data)
        if data.ndim != 3 or min(data.shape) < 1:
            raise ValueError(f"data must be a non-empty 3-D array indexed [z, y, x], got shape {data.shape}")
        if not np.issubdtype(data.dtype, np.number) or np.issubdtype(data.dtype, np.complexfloating):
            raise ValueError(f"data must hold real numbers, got dtype {data.dtype}")
        self.data = np.ascontiguousarray(data, dtype=np.float32)
        if self.spacing_mm is None:
            raise ValueError(
                "a CBCT volume without spacing has no geometry: spacing_mm must be the voxel size "
                "(dx, dy, dz) in mm, got None"
            )
        self.spacing_mm = _vec3(self.spacing_mm, "spacing_mm", positive=True)
        self.origin_mm = _vec3(self.origin_mm, "origin_mm")

    @classmethod
    def from_bounds(cls, lower_mm, upper_mm, spacing_mm, fill: float = 0.0) -> "Volume":
        """A volume filled with ``fill`` whose voxel centres span ``[lower_mm, upper_mm]`` (world, mm).

        The grid starts at ``lower_mm`` and holds as many whole voxels as fit up to ``upper_mm``
        (at least one per axis).
        """
        lo = _vec3(lower_mm, "lower_mm")
        hi = _vec3(upper_mm, "upper_mm")
        sp = _vec3(spacing_mm, "spacing_mm", positive=True)
        if np.any(hi < lo):
            raise ValueError(f"upper_mm must be >= lower_mm on every axis, got lower_mm={lo.tolist()}, upper_mm={hi.tolist()}")
        n = np.floor((hi - lo) / sp + 1e-9).astype(int) + 1
        return cls(np.full((n[2], n[1], n[0]), fill, dtype=np.float32), sp, lo)

    @property
    def shape_xyz(self) -> tuple[int, int, int]:
        """Number of voxels along ``(x, y, z)``."""
        nz, ny, nx = self.data.shape
        return (nx, ny, nz)

    @property
    def voxel_volume_mm3(self) -> float:
        return float(np.prod(self.spacing_mm))

    @property
    def lower_mm(self) -> np.ndarray:
        """World position of the first voxel centre (= ``origin_mm``)."""
        return self.origin_mm.copy()

    @property
    def upper_mm(self) -> np.ndarray:
        """World position of the last voxel centre."""
        return self.origin_mm + (np.asarray(self.shape_xyz) - 1) * self.spacing_mm

    def world_to_voxel(self, points_mm) -> np.ndarray:
        """Continuous voxel coordinates ``(i, j, k)`` (x, y, z order) of world points, ``(n, 3)``."""
        return (as_points(points_mm) - self.origin_mm) / self.spacing_mm

    def voxel_to_world(self, ijk) -> np.ndarray:
        """World points (mm) of continuous voxel coordinates ``(i, j, k)`` (x, y, z order), ``(n, 3)``."""
        return self.origin_mm + as_points(ijk, "ijk") * self.spacing_mm

    def axes_mm(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World coordinates of the voxel centres along x, y and z (three 1-D arrays)."""
        return tuple(self.origin_mm[a] + np.arange(self.shape_xyz[a]) * self.spacing_mm[a] for a in range(3))

    def world_points(self) -> np.ndarray:
        """World coordinates of every voxel centre, ``(nz, ny, nx, 3)`` in (x, y, z) order."""
        x, y, z = self.axes_mm()
        Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
        return np.stack([X, Y, Z], axis=-1)

    def sample(self, points_mm, outside: float = np.nan) -> np.ndarray:
        """``V(x)``: trilinear interpolation at world points (§II-A); ``outside`` beyond the voxel centres.

        Returns float64 ``(n,)``. A point counts as inside when it lies within the box spanned
        by the voxel centres (interpolation needs a neighbour on each side).
        """
        ijk = self.world_to_voxel(points_mm)
        coords = ijk[:, ::-1].T  # map_coordinates wants array order (z, y, x)
        values = ndimage.map_coordinates(self.data, coords, order=1, mode="nearest", output=np.float64)
        n = np.asarray(self.shape_xyz)
        eps = 1e-9
        inside = np.all((ijk >= -eps) & (ijk <= n - 1 + eps), axis=1)
        return np.where(inside, values, outside)

    def contains(self, points_mm) -> np.ndarray:
        """Whether world points lie within the box spanned by the voxel centres, ``(n,)`` bool."""
        ijk = self.world_to_voxel(points_mm)
        n = np.asarray(self.shape_xyz)
        return np.all((ijk >= -1e-9) & (ijk <= n - 1 + 1e-9), axis=1)

    def with_data(self, data) -> "Volume":
        """A volume on the same grid holding ``data`` (same shape required)."""
        data = np.asarray(data)
        if data.shape != self.data.shape:
            raise ValueError(f"data must have the volume's shape {self.data.shape}, got {data.shape}")
        return Volume(data, self.spacing_mm.copy(), self.origin_mm.copy())


def _check_volume(volume, name: str = "volume") -> Volume:
    if not isinstance(volume, Volume):
        raise TypeError(f"{name} must be a histostudy.cbct.Volume, got {type(volume).__name__}")
    return volume


def _check_mask(mask, volume: Volume, name: str) -> np.ndarray:
    arr = np.asarray(mask)
    if arr.shape != volume.data.shape:
        raise ValueError(f"{name} must be a boolean array of the volume's shape {volume.data.shape} ([z, y, x]), got {arr.shape}")
    if arr.dtype != bool:
        raise ValueError(f"{name} must be a boolean array, got dtype {arr.dtype}")
    return arr


# ---------------------------------------------------------------------------------------------
# Phantom (§II-D.1)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PhantomSpec:
    """The layered agarose / agarose-barium phantom of §II-D.1, in water.

    Geometry (phantom frame: origin at the cube centre, axes along the cube edges, layers stacked
    along +z): a cube of ``size_mm`` (paper: 5x5x5 cm mold) of layers ``layer_thickness_mm``
    thick (paper: "approximately 4 mm"), starting at the bottom face (z = -size/2) with
    ``first_layer`` ("agarose" or "barium"), alternating.

    Gray values, HU — assumptions of this study (the paper gives recipes, not CT numbers):

    - ``water_hu = 0``: saline bath, by the definition of the HU scale;
    - ``agarose_hu = 30``: 1.5 % agarose in saline with 5 % red blood cells, a little denser than
      water (soft-tissue-like);
    - ``barium_hu = 450``: the same with 10 g BaSO4 in ~420 mL (~2.4 % w/v), in the range of dilute
      barium suspensions used as CT contrast (~15-20 HU per mg/mL at 120 kVp).

    The contrast between layers (420 HU) is what makes the mixed zone visible (a medium value,
    ~240 HU, without layer texture).
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
        first, second = (self.agarose_hu, self.barium_hu) if self.first_layer == "agarose" else (self.barium_hu, self.agarose_hu)
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

    The grid covers the phantom's bounding box plus ``margin_mm`` of water on every side, with
    voxel size ``spacing_mm`` (scalar or (3,)). Each voxel is the mean of ``supersample**3``
    sub-voxel samples, so that layer and cube edges get partial-volume values as a scanner's
    detector integration would give them.
    """
    T = _check_T(T_carm_phantom)
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be finite and >= 0, got {margin_mm!r}")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or supersample < 1:
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
    sp = _vec3(spacing_mm, "spacing_mm", positive=True)
    h = 0.5 * spec.size_mm
    corners = np.array([[sx, sy, sz] for sx in (-h, h) for sy in (-h, h) for sz in (-h, h)])
    world = transform_points(T, corners)
    lo = world.min(axis=0) - margin_mm
    hi = world.max(axis=0) + margin_mm
    vol = Volume.from_bounds(lo, hi, sp)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    first, second = (spec.agarose_hu, spec.barium_hu) if spec.first_layer == "agarose" else (spec.barium_hu, spec.agarose_hu)
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


def phantom_mask(volume: Volume, spec: PhantomSpec = PhantomSpec(), T_carm_phantom=None, margin_mm: float = 0.0) -> np.ndarray:
    """Boolean ``[z, y, x]`` mask of the voxels whose centre lies in the phantom cube shrunk by ``margin_mm``."""
    volume = _check_volume(volume)
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
    """A reconstructed CBCT of the true attenuation ``truth`` (the scanner stand-in, §II-D).

    The scanner's point-spread function is an isotropic Gaussian of standard deviation
    ``blur_sigma_mm`` (``scipy.ndimage.gaussian_filter``); the volume is then resampled
    (trilinearly) onto voxels of ``voxel_mm`` (scalar or (3,); default: ``truth``'s grid) over the
    same extent, and white Gaussian noise of ``noise_sd_hu`` is added per voxel — a stand-in for
    reconstruction noise, whose real spectrum is not white (an assumption). ``rng``: a Generator
    or int seed.
    """

    truth = _check_volume(truth, "truth")
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
        sp = _vec3(voxel_mm, "voxel_mm", positive=True)
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
    """Validate a target the user picked in the pre-treatment CBCT; return it as float64 (3,) mm.

    The target (world, mm) must lie inside the phantom cube at least ``margin_mm`` from its faces
    (pass the zone radius to keep the whole zone in the phantom) and, when ``volume`` is given,
    inside that volume. Raises ValueError naming ``target_mm``, its value and the violated bound.
    """
    t = np.asarray(target_mm, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"target_mm must be 3 finite numbers (world x, y, z in mm), got {target_mm!r}")
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise ValueError(f"margin_mm must be finite and >= 0, got {margin_mm!r}")
    T = _check_T(T_carm_phantom)
    if volume is not None:
        volume = _check_volume(volume)
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
    """A target drawn uniformly inside the phantom at least ``border_mm`` from every face (world, mm).

    For the study: ``border_mm`` >= the zone radius plus a safety margin keeps the whole
    treatment zone (and the segmentation window) inside the phantom. ``rng``: Generator or seed.
    """

    gen = as_generator(rng)
    half = 0.5 * spec.size_mm - border_mm
    if not (math.isfinite(border_mm) and border_mm >= 0) or half < 0:
        raise ValueError(
            f"border_mm must be in [0, {0.5 * spec.size_mm}] mm for a {spec.size_mm} mm phantom, got {border_mm!r}"
        )
    local = gen.uniform(-half, half, size=3)
    return transform_points(_check_T(T_carm_phantom), local)[0]


@dataclass(frozen=True)
class TreatmentZone:
    """The prescribed spherical treatment zone (§II-D): centre (world, mm) and diameter (mm).

    The paper's studies use 20 and 25 mm (:data:`PAPER_ZONE_DIAMETERS_MM`); any diameter > 0 is
    accepted here.
    """

    centre_mm: np.ndarray
    diameter_mm: float = 20.0

    def __post_init__(self):
        c = np.asarray(self.centre_mm, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"centre_mm must be 3 finite numbers (world mm), got {self.centre_mm!r}")
        object.__setattr__(self, "centre_mm", c)
        d = self.diameter_mm
        if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)) or not (math.isfinite(d) and d > 0):
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
        volume = _check_volume(volume)
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
    """The treated (mixed) zone found in a post-treatment CBCT, world mm.

    ``mask``: bool ``[z, y, x]`` on the CBCT grid. ``centroid_mm``: mean voxel-centre position
    of the mask (the paper's reference point, §II-E.3-4). ``sphere_centre_mm`` /
    ``sphere_radius_mm``: least-squares sphere (:func:`histostudy.geometry.fit_sphere`) through
    the mask's boundary faces. ``equivalent_radius_mm``: radius of the ball of the mask's volume.
    ``layered_variance`` / ``homogeneous_variance`` / ``threshold_variance``: the local-variance
    levels (HU^2) of untreated phantom, of homogeneous material, and the threshold between them
    (the coarse stage). ``zone_level_hu``: the mixed material's gray value;
    ``layered_deviation`` / ``homogeneous_deviation``: the local mean deviation from it, in units
    of each layer material's own distance from it (1 on an untreated voxel, 0 on a mixed one), in
    untreated phantom and inside the zone; ``treated_fraction_threshold``: the treated fraction of
    the boundary window at which the boundary was put (the boundary stage).
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
    """Segment the mixed (treated) zone in a post-treatment CBCT of the layered phantom (§II-E.3-4).

    The automatic stand-in for the paper's manual annotation, in two stages.

    **Coarse stage: where is the zone.** In a window spanning one layer period (``window_mm``,
    default 8 mm = 2 x 4 mm layers) untreated phantom holds both materials, so its local variance
    is ``v_l ~ (contrast/2)^2 + noise``; the mixed zone is homogeneous, its local variance the
    noise alone, ``v_h``. Voxels below ``(v_l + v_h) / 2`` inside the phantom, largest component.
    This finds the zone robustly but puts its boundary up to a voxel inside: a window straddling
    the boundary parallel to the layers holds one layer, whose variance is not that of the layer
    texture, and on a convex zone the half-treated window lies inside the surface.

    **Boundary stage: where exactly does it end.** The mixed material's gray value ``mu`` (median
    inside the coarse zone) lies between the two layer materials, so every untreated voxel
    deviates from it by that material's distance from it whatever the layer's phase, and a voxel
    half in the zone (partial volume, scanner blur) by half that: the deviation ``|V - mu|`` in
    units of the nearer material's distance (its median level in untreated phantom), averaged
    over a box of about one layer (``boundary_window_mm``), is linear in the window's untreated
    fraction, from ``e_h`` (noise, inside the zone) to ``e_l`` (untreated phantom). The boundary is put where the window's treated fraction equals the fraction the box
    filter of the segmented shape itself takes on its surface (a self-consistent threshold,
    ``n_refinements`` passes from 1/2): 1/2 on a flat boundary, less on a curved one, so that the
    window's curvature bias cancels.

    Measured on 1 mm CBCTs of the rotated layered phantom treated in 20 and 25 mm spheres (6 per
    level, default parameters; ``tests/test_cbct.py`` checks the 0.5 mm / 20 HU level): fitted
    sphere radius bias -0.02, +0.07, +0.11 and +0.44 mm at blur/noise 0/0, 0.5 mm/20 HU,
    1 mm/40 HU and 1.5 mm/80 HU (the coarse stage alone: -0.46, -0.31, -0.18, -0.10); largest
    radius error along an oblique axis 0.27, 0.30, 0.66, 1.00 mm (coarse stage: 0.93, 0.55, 0.53,
    1.18); centroid error 0.04-0.07 mm up to 1 mm/40 HU, 0.16 mm at 1.5 mm/80 HU.

    Levels: ``v_l`` and ``e_l`` are medians over the phantom eroded by half a window and without
    the zone grown by a window; ``v_h`` = ``noise_variance`` if given, else the median local
    variance of the water outside ``roi_mask`` grown by a whole window (so the volume needs about
    ``window_mm`` + a few mm of water around the phantom: :func:`phantom_volume`'s default margin
    gives it); ``e_h`` the median inside the coarse zone eroded by a boundary window. Gaussian
    smoothing (``smoothing_sigma_mm``) against noise first.

    ``roi_mask``: bool ``[z, y, x]``, the phantom (e.g. :func:`phantom_mask`). Raises ValueError
    when nothing is found or the levels cannot be estimated.
    """
    volume = _check_volume(volume)
    roi = _check_mask(roi_mask, volume, "roi_mask")
    for name, value in (("window_mm", window_mm), ("boundary_window_mm", boundary_window_mm)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0 (about one layer period / one layer), got {value!r}")
    if not (math.isfinite(smoothing_sigma_mm) and smoothing_sigma_mm >= 0):
        raise ValueError(f"smoothing_sigma_mm must be finite and >= 0, got {smoothing_sigma_mm!r}")
    if isinstance(n_refinements, bool) or not isinstance(n_refinements, (int, np.integer)) or n_refinements < 0:
        raise ValueError(f"n_refinements must be an integer >= 0, got {n_refinements!r}")
    sp_zyx = volume.spacing_mm[::-1]
    data = volume.data.astype(np.float64)
    if smoothing_sigma_mm > 0:
        data = ndimage.gaussian_filter(data, sigma=smoothing_sigma_mm / sp_zyx, mode="nearest")
    size = _odd_box(window_mm, sp_zyx)
    mean = ndimage.uniform_filter(data, size=size, mode="nearest")
    var = np.maximum(ndimage.uniform_filter(data * data, size=size, mode="nearest") - mean * mean, 0.0)

    # Away from the phantom's faces by half a window: there the water/phantom step dominates.
    # (Box erosions/dilations as separable min/max filters: fast for large windows.)
    interior = ~ndimage.maximum_filter(~roi, size=size, mode="constant", cval=True)
    if interior.sum() < 10:
        raise ValueError(
            f"roi_mask leaves {int(interior.sum())} voxels once eroded by half of window_mm={window_mm}: "
            "the phantom region is too small for the segmentation window"
        )
    if noise_variance is not None:
        if not (math.isfinite(noise_variance) and noise_variance >= 0):
            raise ValueError(f"noise_variance must be finite and >= 0 (HU^2), got {noise_variance!r}")
        v_h = float(noise_variance)
    else:
        # Water at least a whole window from the phantom, so that neither the window nor the
        # scanner's blur of the phantom's faces reaches into what is measured as pure noise.
        water = ~ndimage.maximum_filter(roi, size=2 * size + 1, mode="nearest")
        if water.sum() < 100:
            raise ValueError(
                f"the volume holds only {int(water.sum())} water voxels a window away from roi_mask, too few "
                "to measure the homogeneous (noise) variance: give a volume with water around the phantom "
                "or pass noise_variance"
            )
        v_h = float(np.median(var[water]))

    def coarse(v_l: float) -> np.ndarray:
        if not v_l > v_h:
            raise ValueError(
                f"no layer texture: the phantom's local variance ({v_l:.3g} HU^2) does not exceed that of "
                f"homogeneous material ({v_h:.3g} HU^2)"
            )
        return _largest_component((var < 0.5 * (v_l + v_h)) & interior, "local variance")

    # Two passes: the median over the whole interior is pulled down by the zone and by the shell
    # where windows straddle its boundary; the second pass takes the median over the interior
    # without the first zone grown by a window (+ a voxel for blur), i.e. over untreated phantom.
    mask = coarse(float(np.median(var[interior])))
    untreated = interior & ~ndimage.maximum_filter(mask, size=size + 2, mode="constant", cval=False)
    if untreated.sum() >= 0.1 * interior.sum():
        v_l = float(np.median(var[untreated]))
        mask = coarse(v_l)
        untreated = interior & ~ndimage.maximum_filter(mask, size=size + 2, mode="constant", cval=False)
    else:  # the zone leaves too little untreated phantom to measure: keep the first pass
        v_l = float(np.median(var[interior]))
    thr = 0.5 * (v_l + v_h)

    # Boundary stage (see the docstring).
    small = _odd_box(boundary_window_mm, sp_zyx)
    core = ~ndimage.maximum_filter(~mask, size=small, mode="constant", cval=True)
    if core.sum() < 10 or untreated.sum() < 10:
        raise ValueError(
            f"the coarse zone ({int(mask.sum())} voxels) leaves {int(core.sum())} voxels once eroded by "
            f"boundary_window_mm={boundary_window_mm} and {int(untreated.sum())} untreated phantom voxels: "
            "too few to measure the boundary stage's levels"
        )
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
    inside_phantom = ~ndimage.maximum_filter(~roi, size=small, mode="constant", cval=True)
    treated_fraction = 0.5
    for step in range(n_refinements + 1):
        if step:
            treated_fraction = _boundary_window_fraction(mask, small)
        mask = _largest_component((deviation < e_h + (1.0 - treated_fraction) * (e_l - e_h)) & inside_phantom,
                                  "deviation from the zone's level")

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
        threshold_variance=thr,
        spacing_mm=volume.spacing_mm.copy(),
        origin_mm=volume.origin_mm.copy(),
        zone_level_hu=mu,
        layered_deviation=e_l,
        homogeneous_deviation=e_h,
        treated_fraction_threshold=treated_fraction,
    )
