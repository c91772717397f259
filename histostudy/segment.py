"""Deprecated path: ``histostudy.segment`` moved to :mod:`histostudy.learning` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.learning import (OracleSegmenter, SegmentationDegradation, Segmenter, UNetSegmenter,
                                 default_segmenter, keep_largest_component, masks_from_labels)

__all__ = ["OracleSegmenter", "SegmentationDegradation", "Segmenter", "UNetSegmenter", "default_segmenter", "keep_largest_component", "masks_from_labels"]

warnings.warn("histostudy.segment is deprecated: import from histostudy.learning instead", DeprecationWarning, stacklevel=2)
