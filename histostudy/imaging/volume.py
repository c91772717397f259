"""CBCT volumes (§II-A): an axis-aligned voxel grid in the world frame (LPS, mm, HU), data indexed
``[z, y, x]``, trilinear between voxel centres; its checks, and the LPS/RAS conversions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from histostudy.geometry import as_points

__all__ = ["LPS_FROM_RAS", "Volume", "check_mask", "check_volume", "lps_from_ras", "ras_from_lps", "vector3_mm"]

#: RAS (NIfTI, nibabel, 3D Slicer) -> LPS (DICOM; the world frame, :data:`histostudy.core.WORLD_FRAME`):
#: x and y change sign, z is shared. Its own inverse.
LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0])


def lps_from_ras(points_ras_mm) -> np.ndarray:
    """World points (LPS) of points in RAS, as nibabel's affine or 3D Slicer gives them.

    Args:
        points_ras_mm: ``(n, 3)`` or ``(3,)`` points in RAS mm.

    Returns:
        ``(n, 3)`` float64 points in LPS mm (x and y negated).

    Raises:
        ValueError: ``points_ras_mm`` is not ``(n, 3)`` or ``(3,)``.
    """
    return as_points(points_ras_mm, "points_ras_mm") @ LPS_FROM_RAS.T


def ras_from_lps(points_lps_mm) -> np.ndarray:
    """Points in RAS, as nibabel and 3D Slicer show them, of world points (LPS).

    Args:
        points_lps_mm: ``(n, 3)`` or ``(3,)`` world points in LPS mm.

    Returns:
        ``(n, 3)`` float64 points in RAS mm (x and y negated).

    Raises:
        ValueError: ``points_lps_mm`` is not ``(n, 3)`` or ``(3,)``.
    """
    return as_points(points_lps_mm, "points_lps_mm") @ LPS_FROM_RAS.T


def vector3_mm(value, name: str, positive: bool = False) -> np.ndarray:
    """A length in mm per axis, checked.

    Args:
        value: 3 numbers in mm, ``(x, y, z)`` order, or a scalar (broadcast to all three).
        name: what the error message calls ``value``.
        positive: require every component > 0.

    Returns:
        A finite float64 ``(3,)`` array.

    Raises:
        ValueError: ``value`` is None, not 3 finite numbers, or (with ``positive``) not > 0.
    """
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

    Voxel coordinates ``(i, j, k)`` are continuous indices in ``(x, y, z)`` order:
    ``world = origin_mm + (i, j, k) * spacing_mm``.

    Args:
        data: 3-D array of real numbers indexed ``[iz, iy, ix]``; stored as contiguous float32.
        spacing_mm: voxel size ``(dx, dy, dz)`` in mm (a scalar is broadcast), required and > 0: a
            volume without spacing has no geometry.
        origin_mm: world position ``(x, y, z)`` in mm of the centre of voxel ``[0, 0, 0]``.
        T_world_file_voxel: (4, 4) affine from the voxel indices of the file the volume was read from
            (which may run along other axes or directions) to world mm (:meth:`file_voxel_to_world`);
            None for a volume not read from a file.

    Raises:
        ValueError: ``data`` is not a non-empty 3-D real array; ``spacing_mm`` is None, not finite or
            not > 0; ``origin_mm`` is not 3 finite numbers; ``T_world_file_voxel`` is not a finite,
            invertible 4x4 affine with last row ``0 0 0 1``.
    """

    data: np.ndarray
    spacing_mm: np.ndarray  # None is refused, naming what a CBCT needs
    origin_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    T_world_file_voxel: np.ndarray | None = None

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
        self.spacing_mm = vector3_mm(self.spacing_mm, "spacing_mm", positive=True)
        self.origin_mm = vector3_mm(self.origin_mm, "origin_mm")
        if self.T_world_file_voxel is not None:
            T = np.asarray(self.T_world_file_voxel, dtype=np.float64)
            if (T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[3], [0, 0, 0, 1])
                    or abs(np.linalg.det(T[:3, :3])) == 0):
                raise ValueError("T_world_file_voxel must be a finite, invertible 4x4 affine (file voxel -> world "
                                 f"mm, last row 0 0 0 1) or None, got {self.T_world_file_voxel!r}")
            self.T_world_file_voxel = T

    @classmethod
    def from_bounds(cls, lower_mm, upper_mm, spacing_mm, fill: float = 0.0) -> Volume:
        """A volume filled with ``fill`` whose voxel centres span ``[lower_mm, upper_mm]`` (world, mm).

        The grid starts at ``lower_mm`` and holds as many whole voxels as fit up to ``upper_mm``
        (at least one per axis).
        """
        lo = vector3_mm(lower_mm, "lower_mm")
        hi = vector3_mm(upper_mm, "upper_mm")
        sp = vector3_mm(spacing_mm, "spacing_mm", positive=True)
        if np.any(hi < lo):
            raise ValueError(f"upper_mm must be >= lower_mm on every axis, got lower_mm={lo.tolist()}, "
                             f"upper_mm={hi.tolist()}")
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

    def file_voxel_to_world(self, ijk) -> np.ndarray:
        """World points (LPS mm, ``(n, 3)``) of voxel indices ``(i, j, k)`` as the volume's file
        indexes its voxels: nibabel's ``(i, j, k)`` of a NIfTI's array (3D Slicer's IJK), or
        ``(column, row, slice)`` of a DICOM volume, its slices sorted along their normal (§II-D: the
        voxel a user reads off a viewer). A volume not read from a file is its own file's grid
        (:func:`~histostudy.imaging.save_volume_nifti` writes it so): :meth:`voxel_to_world`."""
        points = as_points(ijk, "ijk")
        if self.T_world_file_voxel is None:
            return self.voxel_to_world(points)
        return points @ self.T_world_file_voxel[:3, :3].T + self.T_world_file_voxel[:3, 3]

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

    def with_data(self, data) -> Volume:
        """A volume on the same grid holding ``data`` (same shape required)."""
        data = np.asarray(data)
        if data.shape != self.data.shape:
            raise ValueError(f"data must have the volume's shape {self.data.shape}, got {data.shape}")
        return Volume(data, self.spacing_mm.copy(), self.origin_mm.copy(),
                      None if self.T_world_file_voxel is None else self.T_world_file_voxel.copy())


def check_volume(volume, name: str = "volume") -> Volume:
    """An argument checked to be a :class:`Volume`.

    Args:
        volume: the object to check.
        name: what the error message calls ``volume``.

    Returns:
        ``volume`` itself.

    Raises:
        TypeError: ``volume`` is not a :class:`Volume`.
    """
    if not isinstance(volume, Volume):
        raise TypeError(f"{name} must be a histostudy.imaging.volume.Volume, got {type(volume).__name__}")
    return volume


def check_mask(mask, volume: Volume, name: str) -> np.ndarray:
    """A mask checked against a volume's grid.

    Args:
        mask: boolean array indexed ``[z, y, x]``.
        volume: the :class:`Volume` whose shape ``mask`` must have.
        name: what the error message calls ``mask``.

    Returns:
        ``mask`` as a bool ndarray.

    Raises:
        ValueError: ``mask``'s shape is not ``volume.data.shape`` or its dtype is not bool.
    """
    arr = np.asarray(mask)
    if arr.shape != volume.data.shape:
        raise ValueError(f"{name} must be a boolean array of the volume's shape {volume.data.shape} ([z, y, x]), "
                         f"got {arr.shape}")
    if arr.dtype != bool:
        raise ValueError(f"{name} must be a boolean array, got dtype {arr.dtype}")
    return arr


# ---------------------------------------------------------------------------------------------
# Phantom (§II-D.1)
# ---------------------------------------------------------------------------------------------
