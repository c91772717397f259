"""Notebook 05, calibration, targeting and treatment of the phantom (§II-C, §II-D, §II-E.4, §III,
Fig. 7): its parameters (:class:`TargetingSectionConfig`), :func:`prepare`, the parts :func:`record`
writes and Fig. 7's figures. The experiment layer notebooks 06 and 07 share is public in
:mod:`.setup`, :mod:`.robots` and :mod:`.experiment` (docs/targeting-study.md).
"""

from ..section import record
from ._calibration import calibration_poses
from ._figures import fig7_figures, plot_target_slices, scene_figure
from ._section import (
    SECTION_TITLE,
    TargetingSectionConfig,
    calibration_part,
    closing_part,
    experiments_section,
    prepare,
    sensitivity_section,
    targeting_part,
)
from ._treatment import phantom_for

__all__ = [
    "SECTION_TITLE",
    "TargetingSectionConfig",
    "calibration_part",
    "calibration_poses",
    "closing_part",
    "experiments_section",
    "fig7_figures",
    "phantom_for",
    "plot_target_slices",
    "prepare",
    "record",
    "scene_figure",
    "sensitivity_section",
    "targeting_part",
]
