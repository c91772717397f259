"""Notebook 03, the VGG19 azimuth and elevation regression (§II-B.4 eq. 4, §II-E.2, §III):
:class:`OrientationConfig`, :func:`prepare`, the part functions and :func:`record`
(``from histostudy.study import orientation as study``), and the evaluation scripts use.
"""

from ..held_out import weights_part, weights_summary
from ..section import record
from ._section import (
    INITIALISER_RNG_SEED,
    SECTION,
    TITLE,
    AngleEvaluation,
    InitialiserComparison,
    OrientationConfig,
    OrientationSetup,
    angle_statistics_part,
    angle_table,
    candidate_error_summary,
    candidate_errors,
    direction_error_part,
    direction_error_summary,
    evaluate_orientation,
    evaluation_section,
    initialiser_comparison_section,
    load_vgg19,
    orientation_initialisers,
    prepare,
    scatter_figure,
    stand_ins_part,
)

__all__ = [
    "INITIALISER_RNG_SEED",
    "SECTION",
    "TITLE",
    "AngleEvaluation",
    "InitialiserComparison",
    "OrientationConfig",
    "OrientationSetup",
    "angle_statistics_part",
    "angle_table",
    "candidate_error_summary",
    "candidate_errors",
    "direction_error_part",
    "direction_error_summary",
    "evaluate_orientation",
    "evaluation_section",
    "initialiser_comparison_section",
    "load_vgg19",
    "orientation_initialisers",
    "prepare",
    "record",
    "scatter_figure",
    "stand_ins_part",
    "weights_part",
    "weights_summary",
]
