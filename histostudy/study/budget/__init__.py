"""Notebook 07: the error budget (§III, §IV) — the lab's error sources simulated, both studies run
with all of them on, each alone and all but one, on the same draws.

Its modules, one job each: the sources' magnitudes (``_magnitudes``) and where each comes from
(``_references``), the lab's error sources and one lab's draws of them (``_sources``), the
runs under every configuration on :func:`histostudy.core.run_sweep` (``_run``), the figures, shares
and comparisons with the paper (``_summary``), the notebook's parameters
(:class:`BudgetSectionConfig`), set-up (:func:`prepare`), seeds and parts recorded by :func:`record`
(``_notebook``); many labs drawn and run (``_labs``), their figures beside the paper's
(``_distribution``) and the notebook's part of them (``_labs_notebook``); the renders and
segmentations shared by runs whose frames are alike (``_shared``); the sources without a fitting
measurement run at both ends of their range (``_ranges``).
"""

from . import (
                        _distribution,
                        _labs,
                        _labs_notebook,
                        _magnitudes,
                        _notebook,
                        _ranges,
                        _references,
                        _run,
                        _shared,
                        _sources,
                        _summary,
)
from ._distribution import (
                        BAND_PERCENT,
                        MOVER_METRICS,
                        NATIVE_READING,
                        PAPER_FIGURES,
                        READINGS,
                        bias_scatter_split,
                        lab_statistics,
                        labs_vs_paper,
                        paper_statistics,
                        sign_agreement,
                        source_movers,
)
from ._labs import LAB_MAGNITUDES, draw_labs, frames_alike, lab_magnitudes, lab_seed, labs_records, run_labs
from ._labs_notebook import LabsSection, labs_figure, labs_section, labs_text, movers_table, prepare_labs
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
from ._notebook import (
                        RECORDED_PARAMETERS,
                        SECTION_TITLE,
                        SOURCE_PROVENANCE,
                        BudgetRun,
                        BudgetSectionConfig,
                        BudgetSeeds,
                        SectionPart,
                        SharesSection,
                        budget_section,
                        budget_seeds,
                        closing_part,
                        closing_text,
                        lab_model_from_parameters,
                        prepare,
                        prepare_budget,
                        record,
                        shares_section,
                        sources_part,
                        sources_table,
                        stand_ins,
)
from ._ranges import FRAME_SOURCES, RANGE_ENDS, RangesSection, range_bands, range_labs, ranges_section, run_ranges
from ._references import (
                        SOURCE_REFERENCES,
                        STATUSES,
                        SourceReference,
                        magnitudes_at,
                        model_at,
                        references_table,
                        sweep_values,
)
from ._run import (
                        ESTIMATE_SOURCES,
                        BudgetSetup,
                        budget_configurations,
                        measured_reference,
                        measured_zone,
                        run_error_budget,
)
from ._shared import SharedSegmentations, shared_work
from ._sources import LAB_SOURCES, ExperimentDraw, LabDraw, LabErrorModel, draw_lab
from ._summary import (
                        STUDY_COLUMNS,
                        budget_comparisons,
                        configuration_table,
                        dominant_sources,
                        paired_errors,
                        source_shares,
                        waterfall_figure,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_magnitudes.__all__, *_notebook.__all__, *_references.__all__, *_run.__all__,
                              *_sources.__all__, *_summary.__all__, *_distribution.__all__, *_labs.__all__,
                              *_labs_notebook.__all__, *_ranges.__all__, *_shared.__all__]))
