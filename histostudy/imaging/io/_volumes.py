"""CBCT volumes from disk (§II-A, §II-D): the reader a path goes to (NIfTI, a DICOM series or an enhanced
DICOM file), each giving a Volume in the LPS C-arm frame, mm, HU (docs/imaging.md, "Volume files")."""

from __future__ import annotations

import os
from pathlib import Path

from ..volume import Volume
from ._dicom import _load_dicom_multiframe, _load_dicom_series
from ._nifti import _load_nifti

__all__ = [
    "SUPPORTED_FORMATS",
    "load_volume",
]

#: What :func:`load_volume` reads (for error messages and documentation).
SUPPORTED_FORMATS = (
    "NIfTI (.nii, .nii.gz); a folder holding one DICOM series of single-slice images; "
    "an enhanced multi-frame DICOM file (.dcm, .dicom)"
)


def load_volume(path: str | os.PathLike) -> Volume:
    """A CBCT volume (§II-A, §II-D) read into a :class:`~histostudy.imaging.volume.Volume` in the LPS
    C-arm frame (mm, HU).

    What is reoriented and what is refused: docs/imaging.md, "Volume files".

    Args:
        path: a ``.nii``/``.nii.gz`` file (NIfTI, read with nibabel); a folder (a DICOM series:
            every file in it that pydicom reads as an image, one series only); or a
            ``.dcm``/``.dicom`` file (an enhanced multi-frame DICOM image).

    Returns:
        The volume.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: an unsupported format; a truncated or corrupt file; a file whose geometry
            cannot be read without resampling (oblique, sheared, unevenly spaced) or is missing
            (no spacing/position); non-finite voxel values (NaN/inf), or a non-finite DICOM
            RescaleSlope/RescaleIntercept.
    """
    path = Path(path)
    name = path.name.lower()
    if path.is_dir():
        return _load_dicom_series(path)
    if name.endswith((".nii", ".nii.gz")):
        _require_file(path)
        return _load_nifti(path)
    if name.endswith((".dcm", ".dicom")):
        _require_file(path)
        return _load_dicom_multiframe(path)
    raise ValueError(f"path {str(path)!r}: unsupported CBCT volume format; supported: {SUPPORTED_FORMATS}")


def _require_file(path: Path) -> None:
    if not path.is_file():
        raise FileNotFoundError(f"CBCT volume {str(path)!r} does not exist (or is not a file)")
