"""Notebook 07: the error budget (§III, §IV) — the lab's error sources simulated, both studies run
with all of them on, each alone and all but one, on the same draws.

Its modules, one job each: the lab's error sources and one lab's draws of them (``_sources``), the
runs under every configuration on :func:`histostudy.core.run_sweep` (``_run``), the figures, shares
and comparisons with the paper (``_summary``), the notebook's parameters
(:class:`BudgetSectionConfig`), set-up (:func:`prepare`), seeds and parts recorded by :func:`record`
(``_notebook``).
"""

from . import (_notebook, _run, _sources, _summary)
from ._notebook import (BudgetRun, BudgetSectionConfig, BudgetSeeds, RECORDED_PARAMETERS, SECTION_TITLE,
                        SOURCE_PROVENANCE, SectionPart, SharesSection, budget_section, budget_seeds, closing_part,
                        closing_text, lab_model_from_parameters, prepare, prepare_budget, record, shares_section,
                        sources_part, sources_table, stand_ins)
from ._run import (BudgetSetup, ESTIMATE_SOURCES, budget_configurations, measured_reference, measured_zone,
                   run_error_budget)
from ._sources import (AnnotationError, BubbleOffset, ExperimentDraw, GantrySag, LAB_SOURCES, LabDraw, LabErrorModel,
                       PhantomMotion, ProjectionError, RegistrationError, RobotRepeatability, draw_lab)
from ._summary import (STUDY_COLUMNS, budget_comparisons, configuration_table, dominant_sources, paired_errors,
                       source_shares, waterfall_figure)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_notebook.__all__, *_run.__all__, *_sources.__all__, *_summary.__all__]))
