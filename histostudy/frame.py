"""Deprecated path: ``histostudy.frame`` moved to :mod:`histostudy.imaging` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.imaging import (Frame, load_frame)

__all__ = ["Frame", "load_frame"]

warnings.warn("histostudy.frame is deprecated: import from histostudy.imaging instead", DeprecationWarning, stacklevel=2)
