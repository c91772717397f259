"""Notebook 07: the error budget (§III, §IV) — the lab's error sources simulated, both studies run
with all of them on, each alone and all but one on the same draws, and the sources' shares of
the error measured.

The study is split by job; this module gathers their public names, as notebook 07 imports them
(``from histostudy.study import budget as study``):

- :mod:`.lab_errors` — :class:`LabErrorModel`, its sources and one lab's draws;
- :mod:`.error_budget` — the configurations and the runs (:func:`run_error_budget`);
- :mod:`.error_budget_summary` — the tables, the shares, the waterfall and the comparisons;
- :mod:`.error_budget_notebook` — the notebook's parameters, set-up, seeds and prose.
"""

from __future__ import annotations

from ._run import BudgetSetup, ESTIMATE_SOURCES, budget_configurations, measured_reference, measured_zone, \
    run_error_budget
from ._notebook import (RECORDED_PARAMETERS, SECTION_TITLE, SOURCE_PROVENANCE, BudgetSeeds, budget_seeds,
                                    closing_text, lab_model_from_parameters, prepare_budget, sources_table, stand_ins)
from ._summary import (STUDY_COLUMNS, budget_comparisons, configuration_table, dominant_sources,
                                   paired_errors, source_shares, waterfall_figure)
from ._sources import (LAB_SOURCES, AnnotationError, BubbleOffset, ExperimentDraw, GantrySag, LabDraw, LabErrorModel,
                         PhantomMotion, ProjectionError, RegistrationError, RobotRepeatability, draw_lab)

__all__ = ["ESTIMATE_SOURCES", "LAB_SOURCES", "RECORDED_PARAMETERS", "SECTION_TITLE", "SOURCE_PROVENANCE",
           "STUDY_COLUMNS", "AnnotationError", "BubbleOffset", "BudgetSeeds", "BudgetSetup", "ExperimentDraw",
           "GantrySag", "LabDraw", "LabErrorModel", "PhantomMotion", "ProjectionError", "RegistrationError",
           "RobotRepeatability", "budget_comparisons", "budget_configurations", "budget_seeds", "closing_text",
           "configuration_table", "dominant_sources", "draw_lab", "lab_model_from_parameters", "measured_reference",
           "measured_zone", "paired_errors", "prepare_budget", "run_error_budget", "source_shares", "sources_table",
           "stand_ins", "waterfall_figure"]
