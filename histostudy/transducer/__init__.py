"""The histotripsy transducer (§II-B.1, §IV): its spec, feature classes, label priority and
quadrants (``spec``); the weighted point sampling of its cap, walls and screws (``sampling``); the
digital model, point clouds per feature class (``digital``); the physical model the synthetic frames
are rendered from, with the manufacturing mismatch of §IV (``physical``); and the paper's set-up
pose (``placement``).
"""

from . import digital as _digital, physical as _physical, placement as _placement, spec as _spec
from .digital import TransducerModel
from .physical import ManufacturingDeviation
from .placement import pose_facing
from .spec import FEATURE_CLASSES, Feature, LABEL_PRIORITY, TransducerSpec, check_label_image, quadrant_index

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_digital.__all__, *_physical.__all__, *_placement.__all__, *_spec.__all__]))
