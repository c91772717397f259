"""Deprecated path: ``histostudy.render`` moved to :mod:`histostudy.imaging` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.imaging import (add_poisson_noise, background_line_integrals, render_frame, render_labels,
                                render_line_integrals)

__all__ = ["add_poisson_noise", "background_line_integrals", "render_frame", "render_labels", "render_line_integrals"]

warnings.warn("histostudy.render is deprecated: import from histostudy.imaging instead", DeprecationWarning, stacklevel=2)
