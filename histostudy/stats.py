"""Deprecated path: ``histostudy.stats`` moved to :mod:`histostudy.study.stats` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.study.stats import (angle_statistics, anova_oneway, confusion_counts, linear_fit,
                                    mean_absolute_error, pearson, segmentation_metrics, tukey_hsd)

__all__ = ["angle_statistics", "anova_oneway", "confusion_counts", "linear_fit", "mean_absolute_error", "pearson", "segmentation_metrics", "tukey_hsd"]

warnings.warn("histostudy.stats is deprecated: import from histostudy.study.stats instead", DeprecationWarning, stacklevel=2)
