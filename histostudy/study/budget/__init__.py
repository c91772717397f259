"""Notebook 07, the error budget (§III, §IV): its parameters (:class:`BudgetSectionConfig`),
:func:`prepare` and the parts :func:`record` writes; and, for a lab's own figures, the error model
(:class:`LabErrorModel`, its sources' magnitudes and references), one lab drawn (:func:`draw_lab`),
the budget run on it (:func:`run_error_budget`) and many labs (docs/error-budget.md).
"""

from ..section import record
from ._labs import draw_labs, run_labs
from ._labs_section import labs_section, prepare_labs
from ._magnitudes import (
    ISO_2768_M_DEVIATION,
    AnnotationError,
    BubbleOffset,
    CarmReproducibility,
    GantrySag,
    PhantomMotion,
    ProjectionError,
    RegistrationError,
    RobotAccuracy,
    RobotRepeatability,
    TransducerReplacement,
)
from ._ranges import ranges_section, run_ranges
from ._references import SOURCE_REFERENCES, model_at, sweep_values
from ._run import BudgetSetup, run_error_budget
from ._section import (
    SECTION_TITLE,
    BudgetSectionConfig,
    budget_section,
    closing_part,
    prepare,
    shares_section,
    sources_part,
)
from ._sources import LAB_SOURCES, LabErrorModel, draw_lab

__all__ = [
    "ISO_2768_M_DEVIATION",
    "LAB_SOURCES",
    "SECTION_TITLE",
    "SOURCE_REFERENCES",
    "AnnotationError",
    "BubbleOffset",
    "BudgetSectionConfig",
    "BudgetSetup",
    "CarmReproducibility",
    "GantrySag",
    "LabErrorModel",
    "PhantomMotion",
    "ProjectionError",
    "RegistrationError",
    "RobotAccuracy",
    "RobotRepeatability",
    "TransducerReplacement",
    "budget_section",
    "closing_part",
    "draw_lab",
    "draw_labs",
    "labs_section",
    "model_at",
    "prepare",
    "prepare_labs",
    "ranges_section",
    "record",
    "run_error_budget",
    "run_labs",
    "run_ranges",
    "shares_section",
    "sources_part",
    "sweep_values",
]
