"""A volume file's voxel grid put onto the Volume layout (§II-A): an axis-aligned grid in any order or
direction is reordered and flipped without touching a value; an oblique one is refused."""

from __future__ import annotations

import numpy as np

from ..volume import Volume

__all__ = [
    "AXIS_TOLERANCE",
]

#: Largest off-axis component of a unit direction cosine still read as axis-aligned. Files store
#: cosines as float32 (NIfTI) or decimal strings (DICOM), so exact zeros cannot be required.
AXIS_TOLERANCE = 1e-6


def _no_spacing(source: str, detail: str) -> ValueError:
    return ValueError(f"{source}: a CBCT volume without spacing has no geometry: {detail}")


def _require_finite(values: np.ndarray, source: str) -> None:
    """Refuse NaN/inf voxels: they would propagate through every trilinear sample (§II-A) and
    every threshold of the segmentation (§II-E.3) without a trace of where they came from."""
    n_finite = int(np.count_nonzero(np.isfinite(values)))
    if n_finite != values.size:
        n_nan = int(np.count_nonzero(np.isnan(values)))
        raise ValueError(
            f"{source}: {values.size - n_finite} of {values.size} voxel values are not finite "
            f"({n_nan} NaN, {values.size - n_finite - n_nan} infinite); expected finite values "
            "(Hounsfield units for CT): a damaged file or a broken rescale/scaling in its header"
        )


def _axis_aligned_volume(data: np.ndarray, steps_lps: np.ndarray, origin_lps: np.ndarray,
                         source: str, file_axes: tuple[int, int, int] = (0, 1, 2)) -> Volume:
    """The :class:`Volume` of a 3-D array whose axis ``a`` steps by ``steps_lps[:, a]`` (LPS mm).

    ``origin_lps`` is the LPS position of ``data[0, 0, 0]``. The step matrix must be a signed
    permutation times positive scales; axes are flipped and transposed (no value is changed)
    so that the Volume runs along +x, +y, +z. ``file_axes``: the array axis of each of the file's
    voxel indices ``(i, j, k)``, kept as the Volume's ``T_world_file_voxel`` (a user picks a voxel
    in the file's indexing, not in the reoriented grid's).
    """
    _require_finite(data, source)
    steps = np.asarray(steps_lps, dtype=np.float64)
    lengths = np.linalg.norm(steps, axis=0)
    if not np.all(np.isfinite(steps)) or np.any(lengths <= 0):
        raise _no_spacing(source, f"voxel step lengths {lengths.tolist()} mm, expected > 0")
    cosines = steps / lengths
    world_axis = np.argmax(np.abs(cosines), axis=0)
    off_axis = np.abs(cosines).copy()
    off_axis[world_axis, np.arange(3)] = 0.0
    if sorted(world_axis.tolist()) != [0, 1, 2] or off_axis.max() > AXIS_TOLERANCE:
        cos_text = "; ".join(
            f"axis {a}: ({', '.join(f'{c:+.6f}' for c in cosines[:, a])})" for a in range(3)
        )
        raise ValueError(
            f"{source}: the voxel grid is oblique to the LPS world axes (direction cosines of the "
            f"data axes, LPS: {cos_text}; tolerance {AXIS_TOLERANCE}); resampling is not done: "
            "resample the volume onto an axis-aligned grid first"
        )
    origin = np.asarray(origin_lps, dtype=np.float64).copy()
    T_world_file_voxel = np.eye(4)
    T_world_file_voxel[:3, :3] = steps[:, list(file_axes)]
    T_world_file_voxel[:3, 3] = origin
    # The snapped on-axis step is kept, not the vector length: sqrt of a sum of squares would
    # perturb the last bit of the spacing and break exact round trips.
    signed = steps[world_axis, np.arange(3)]
    for a in range(3):
        if signed[a] < 0:
            origin[world_axis[a]] += signed[a] * (data.shape[a] - 1)
            data = np.flip(data, axis=a)
    array_axis_of = [int(np.flatnonzero(world_axis == w)[0]) for w in range(3)]
    data = np.transpose(data, (array_axis_of[2], array_axis_of[1], array_axis_of[0]))
    spacing = np.abs(signed[array_axis_of])
    return Volume(np.ascontiguousarray(data, dtype=np.float32), spacing, origin, T_world_file_voxel)
