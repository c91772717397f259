"""Reading and writing a lab's images (§II-A, §II-D): the one check of an X-ray object every reader
applies and the decoding of its pixels (``xray``), a C-arm's geometry from DICOM (``geometry``), XA
objects written as a C-arm writes them (``_xa``), and CBCT volumes from DICOM or NIfTI (``_volumes``,
over ``_dicom``, ``_nifti`` and the voxel grid checks of ``_grid``). See docs/imaging.md."""

from ._nifti import save_volume_nifti
from ._volumes import load_volume
from ._xa import detector_counts, write_xa
from .geometry import gantry_from_dicom
from .xray import (
    RECEIVABLE_TRANSFER_SYNTAXES,
    X_RAY_SOP_CLASSES,
    XRayObjectRejected,
    check_sop_class,
    check_xray_object,
    read_dicom_file,
    stored_sop_class,
    xray_pixels,
)

__all__ = [
    "RECEIVABLE_TRANSFER_SYNTAXES",
    "X_RAY_SOP_CLASSES",
    "XRayObjectRejected",
    "check_sop_class",
    "check_xray_object",
    "detector_counts",
    "gantry_from_dicom",
    "load_volume",
    "read_dicom_file",
    "save_volume_nifti",
    "stored_sop_class",
    "write_xa",
    "xray_pixels",
]
