"""The histotripsy transducer (§II-B.1, §IV): its spec, feature classes and the digital model
(point clouds per feature class) with the physical model the synthetic frames are rendered from
(``model``).
"""

from .model import (FEATURE_CLASSES, Feature, LABEL_PRIORITY, ManufacturingDeviation, TransducerModel, TransducerSpec,
                    pose_facing, quadrant_index)

__all__ = [
    "FEATURE_CLASSES",
    "Feature",
    "LABEL_PRIORITY",
    "ManufacturingDeviation",
    "TransducerModel",
    "TransducerSpec",
    "pose_facing",
    "quadrant_index",
]
