"""Reading and writing a lab's images: DICOM series and their geometry (``_dicom``, ``_geometry``),
DICOM XA frames as a C-arm writes them (``_xa``), the one check of an X-ray object every reader
applies and the decoding of its pixels (``_xray``), NIfTI volumes (``_nifti``), and the reader a
path goes to (``_volumes``) with the voxel grid checks it applies (``_grid``).
"""

from . import _dicom, _geometry, _grid, _nifti, _volumes, _xa, _xray
from ._dicom import SLICE_POSITION_RTOL
from ._geometry import REQUIRED_GEOMETRY_TAGS, gantry_from_dicom
from ._grid import AXIS_TOLERANCE
from ._nifti import save_volume_nifti
from ._volumes import SUPPORTED_FORMATS, load_volume
from ._xa import XA_SOP_CLASS_UID, detector_counts, write_xa, xa_dataset
from ._xray import (
                    RECEIVABLE_TRANSFER_SYNTAXES,
                    X_RAY_SOP_CLASSES,
                    XRayObjectRejected,
                    check_sop_class,
                    check_xray_object,
                    read_dicom_file,
                    xray_pixels,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_dicom.__all__, *_geometry.__all__, *_grid.__all__, *_nifti.__all__, *_volumes.__all__,
                              *_xa.__all__, *_xray.__all__]))
