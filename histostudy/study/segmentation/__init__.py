"""Notebook 02, the U-Net segmentation: Table I, ANOVA and Tukey HSD (§II-B.2, §II-E.1, §III):
:class:`SegmentationConfig`, :func:`prepare`, the part functions and :func:`record`
(``from histostudy.study import segmentation as study``), and the evaluation scripts use.
"""

from ..held_out import weights_part, weights_summary
from ..section import record
from ._section import (
    SECTION,
    TITLE,
    PrecisionTests,
    SegmentationConfig,
    SegmentationEvaluation,
    SegmentationSetup,
    evaluate_segmentation,
    evaluation_section,
    load_unet,
    precision_tests_section,
    prepare,
    stand_ins_part,
    table1,
    table1_part,
)

__all__ = [
    "SECTION",
    "TITLE",
    "PrecisionTests",
    "SegmentationConfig",
    "SegmentationEvaluation",
    "SegmentationSetup",
    "evaluate_segmentation",
    "evaluation_section",
    "load_unet",
    "precision_tests_section",
    "prepare",
    "record",
    "stand_ins_part",
    "table1",
    "table1_part",
    "weights_part",
    "weights_summary",
]
