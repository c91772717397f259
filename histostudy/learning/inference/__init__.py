"""Running the U-Net of §II-B.2: one entry, :class:`UNetRunner` (``runner``), at a precision of
:data:`PRECISIONS`; the int8 network's calibration (``_int8``), the fused layers (``_fused_conv``)
and the head with its arg-max (``_head_argmax``) behind it. Paths and tolerances: docs/inference.md.
"""

from ._int8 import calibrate_int8, int8_available, int8_calibration_path, save_int8_calibration
from .runner import PRECISIONS, UNetRunner, native_bfloat16

__all__ = ["PRECISIONS", "UNetRunner", "calibrate_int8", "int8_available", "int8_calibration_path", "native_bfloat16",
           "save_int8_calibration"]
