"""Deprecated path: ``histostudy.carm`` moved to :mod:`histostudy.imaging` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.imaging import (View, default_biplane, load_views, save_views)

__all__ = ["View", "default_biplane", "load_views", "save_views"]

warnings.warn("histostudy.carm is deprecated: import from histostudy.imaging instead", DeprecationWarning, stacklevel=2)
