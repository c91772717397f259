"""Notebook 01, the digital transducer model and synthetic biplane projections (§II-A eq. 1-2, §II-B.1,
§II-B.2): :class:`TransducerProjectionsConfig`, :func:`prepare`, the part functions and :func:`record`
(``from histostudy.study import projections as study``).
"""

from ..section import record
from ._section import (
    SECTION,
    TITLE,
    BiplanePair,
    TransducerModels,
    TransducerProjectionsConfig,
    TransducerProjectionsSetup,
    label_content_part,
    label_percentages,
    model_geometry_part,
    point_counts_part,
    prepare,
    render_biplane_pair,
    render_timing_part,
    stand_ins_part,
)

__all__ = [
    "SECTION",
    "TITLE",
    "BiplanePair",
    "TransducerModels",
    "TransducerProjectionsConfig",
    "TransducerProjectionsSetup",
    "label_content_part",
    "label_percentages",
    "model_geometry_part",
    "point_counts_part",
    "prepare",
    "record",
    "render_biplane_pair",
    "render_timing_part",
    "stand_ins_part",
]
