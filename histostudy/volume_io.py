"""Deprecated path: ``histostudy.volume_io`` moved to :mod:`histostudy.imaging` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.imaging import (AXIS_TOLERANCE, SLICE_POSITION_RTOL, SUPPORTED_FORMATS, load_volume,
                                save_volume_nifti)

__all__ = ["AXIS_TOLERANCE", "SLICE_POSITION_RTOL", "SUPPORTED_FORMATS", "load_volume", "save_volume_nifti"]

warnings.warn("histostudy.volume_io is deprecated: import from histostudy.imaging instead", DeprecationWarning, stacklevel=2)
