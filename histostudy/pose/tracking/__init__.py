"""Tracking the transducer through a stream of biplane frames (§II-B.3-4): :class:`Tracker`
warm-starts each pose from the last and, with :class:`TrackingConfig`, estimates it on the region
where the last pose projects (:class:`RegionEstimator`). Poses are 4x4 T_carm_transducer in mm;
the design and its measurements are in docs/tracking.md.
"""

from ._options import TrackingConfig
from ._tracker import Tracker
from ._warm import RegionEstimator

__all__ = ["Tracker", "TrackingConfig", "RegionEstimator"]
