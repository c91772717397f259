"""CBCT volumes in NIfTI files (``.nii``, ``.nii.gz``; §II-A, §II-D), read into and written from a Volume:
RAS in the file, LPS mm here; writing then reading gives back the same data bit for bit."""

from __future__ import annotations

import gzip
import io
import os
import warnings
import zlib
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path

from ..volume import Volume
from ._grid import _axis_aligned_volume, _no_spacing

__all__ = [
    "save_volume_nifti",
]

# RAS (NIfTI) <-> LPS (DICOM, our world frame): x and y change sign, z is shared.
_RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0])

# NIfTI spatial units -> mm; 'unknown' is read as mm, as every common tool does.
_NIFTI_UNIT_TO_MM = {"mm": 1.0, "unknown": 1.0, "meter": 1000.0, "micron": 1e-3}


def save_volume_nifti(volume: Volume, path: str | os.PathLike) -> Path:
    """A volume written as NIfTI, atomically, so that :func:`~._volumes.load_volume` reads it back bit
    for bit.

    The data are stored as float32 without scaling and the affine maps voxel indices to RAS mm (the
    LPS world frame with x and y negated). NIfTI-1 keeps its affine in float32; when the spacing or
    origin is not exactly a float32 the file is written as NIfTI-2 (float64 affine) instead.

    Args:
        volume: the :class:`~histostudy.imaging.volume.Volume` (mm).
        path: a ``.nii`` or ``.nii.gz`` file.

    Returns:
        The path written.

    Raises:
        TypeError: ``volume`` is not a Volume.
        ValueError: ``path`` does not end in ``.nii`` or ``.nii.gz``.
        OSError: the file cannot be written.
    """
    import nibabel as nib

    if not isinstance(volume, Volume):
        raise TypeError(f"volume must be a histostudy.imaging.volume.Volume, got {type(volume).__name__}")
    path = Path(path)
    name = path.name.lower()
    if name.endswith(".nii.gz"):
        suffix = ".nii.gz"
    elif name.endswith(".nii"):
        suffix = ".nii"
    else:
        raise ValueError(f"path {str(path)!r}: a NIfTI volume is written to .nii or .nii.gz")
    affine = np.eye(4)
    affine[:3, :3] = _RAS_TO_LPS @ np.diag(volume.spacing_mm)
    affine[:3, 3] = _RAS_TO_LPS @ volume.origin_mm
    exact_in_float32 = np.array_equal(affine.astype(np.float32).astype(np.float64), affine)
    image_class = nib.Nifti1Image if exact_in_float32 else nib.Nifti2Image
    # nibabel indexes (i, j, k) = (x, y, z); the Volume is [z, y, x].
    data = np.ascontiguousarray(volume.data.transpose(2, 1, 0), dtype=np.float32)
    img = image_class(data, affine)
    img.set_data_dtype(np.float32)
    # 'scanner' (code 1): the coordinates are the CBCT scanner's own frame, not a template's.
    img.set_sform(affine, code=1)
    img.set_qform(affine, code=1)
    img.header.set_xyzt_units(xyz="mm")
    with atomic_path(path, suffix=suffix) as tmp:
        nib.save(img, tmp)
    return path


def _load_nifti(path: Path) -> Volume:
    import nibabel as nib
    from nibabel.openers import ImageOpener

    source = f"NIfTI file {str(path)!r}"
    try:
        img = nib.load(str(path))
    except Exception as exc:  # nibabel raises many types for a damaged file; one message for all
        raise ValueError(f"{source} could not be read as NIfTI (truncated or corrupt?): {exc}") from exc
    if not isinstance(img, nib.Nifti1Image):
        raise ValueError(f"{source} is a {type(img).__name__}, expected a NIfTI-1/NIfTI-2 image")
    try:
        contents = None
        if path.name.lower().endswith(".gz"):
            # nibabel reads a .gz only as far as the voxels go, so a file cut inside the gzip
            # trailer (CRC, length) loads silently; reading the whole stream once checks both.
            with gzip.open(path, "rb") as fh:
                contents = fh.read()
            img = type(img).from_bytes(contents)
        hdr = img.header
        # nibabel silently "fixes" a zero pixdim to 1 on load (a 1 mm grid nobody measured), so the
        # voxel sizes are checked in the header as written.
        with (io.BytesIO(contents) if contents is not None else ImageOpener(str(path))) as fh:
            raw_hdr = type(hdr).from_fileobj(fh, check=False)
    except (OSError, EOFError, zlib.error) as exc:
        raise ValueError(f"{source} is truncated or corrupt: {type(exc).__name__}: {exc}") from exc
    shape = tuple(int(n) for n in img.shape)
    if len(shape) < 3 or any(n != 1 for n in shape[3:]):
        raise ValueError(
            f"{source} has shape {shape}; expected a 3-D volume (a 4-D image only with a last axis of length 1)"
        )
    zooms = [float(z) for z in raw_hdr["pixdim"][1:4]]
    # A negative pixdim is an old ANALYZE habit (the sign is the affine's business); zero is no size.
    if not all(np.isfinite(z) and z != 0 for z in zooms):
        raise _no_spacing(source, f"the header's voxel sizes (pixdim[1:4]) are {zooms}, expected non-zero mm")
    if int(hdr["sform_code"]) == 0 and int(hdr["qform_code"]) == 0:
        warnings.warn(
            f"{source} has neither an sform nor a qform (both codes 0): its position in the C-arm "
            "frame is unknown; nibabel's fallback affine (pixdim sizes, centred grid) is used",
            stacklevel=3,
        )
    unit = hdr.get_xyzt_units()[0]
    if unit not in _NIFTI_UNIT_TO_MM:
        raise ValueError(f"{source}: unsupported spatial unit {unit!r} (expected mm, meter or micron)")
    affine = np.asarray(img.affine, dtype=np.float64) * _NIFTI_UNIT_TO_MM[unit]
    try:
        # get_fdata applies scl_slope/scl_inter; float32 is the Volume's type, so no float64 copy.
        data = np.asarray(img.get_fdata(caching="unchanged", dtype=np.float32))
    except (OSError, EOFError, zlib.error) as exc:
        raise ValueError(
            f"{source} is truncated or corrupt: its voxel data (shape {shape}) could not be read: "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    # the decompressed file is no longer needed; the reorientation below copies the data once more
    del img, contents
    data = data.reshape(shape[:3])
    steps_lps = _RAS_TO_LPS @ affine[:3, :3]
    origin_lps = _RAS_TO_LPS @ affine[:3, 3]
    return _axis_aligned_volume(data, steps_lps, origin_lps, source)
