"""Notebook 04, the pose-estimation study and Table II (§II-B.3, §II-B.4, §II-D, §II-E.3, §III): its
parameters (:class:`PoseSectionConfig`), :func:`prepare`, the parts :func:`record` writes, and the
robustness sweep. The experiment layer notebooks 05 and 07 share is public in :mod:`.experiments`,
:mod:`.geometry`, :mod:`.metrics` and :mod:`.reference` (docs/pose-study.md).
"""

from ..section import record
from ._robustness import robustness_summary, robustness_sweep
from ._section import (
    SECTION_TITLE,
    PoseSectionConfig,
    cbct_reference_part,
    closing_part,
    degradation_part,
    experiments_part,
    learned_stages_part,
    pose_overlay,
    prepare,
    projector_part,
    robustness_part,
    table2_part,
    variants_part,
)

__all__ = [
    "SECTION_TITLE",
    "PoseSectionConfig",
    "cbct_reference_part",
    "closing_part",
    "degradation_part",
    "experiments_part",
    "learned_stages_part",
    "pose_overlay",
    "prepare",
    "projector_part",
    "record",
    "robustness_part",
    "robustness_summary",
    "robustness_sweep",
    "table2_part",
    "variants_part",
]
