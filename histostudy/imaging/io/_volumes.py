"""Real CBCT volumes from disk: NIfTI (read and write) and DICOM (a folder of slices, or one
enhanced multi-frame file), as :class:`~histostudy.imaging.volume.Volume`.

Paper sections: §II-A (a CBCT is a voxel grid whose value between voxel centres is the trilinear
interpolation, :meth:`Volume.sample`), §II-D (the pre-treatment CBCT in which the target is picked
and the post-treatment CBCT in which the treated zone is segmented). The synthetic study makes
these volumes with :func:`~histostudy.imaging.cbct.simulate_cbct`; :func:`load_volume` lets the
lab's own volumes take their place in the same code path. It picks the reader by the path:
NIfTI in :mod:`._nifti` (which also writes), DICOM in :mod:`._dicom`; both put the file's
grid onto the Volume's layout with :mod:`._grid`.

Frames and units: the world frame is the CBCT/C-arm frame in DICOM patient coordinates (LPS:
+x towards the patient's left, +y posterior, +z superior), millimetres. A :class:`Volume` is
axis-aligned with that frame, has positive spacing along +x, +y, +z, and its ``origin_mm`` is the
world position of the centre of voxel ``[0, 0, 0]``; its data are float32, indexed ``[z, y, x]``,
in Hounsfield units for CT (DICOM rescale and NIfTI ``scl_slope``/``scl_inter`` are applied).

A file whose grid is axis-aligned in any order or direction (a signed permutation of the LPS
axes) is reordered and flipped onto that layout without touching a value. An oblique grid, a
sheared series (gantry tilt) or unevenly spaced slices are refused: resampling would interpolate
the gray values the treatment-zone segmentation (§II-E.3) measures, so it is left to the user,
done once and knowingly.
"""

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
