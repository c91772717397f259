"""Tracking the transducer through a stream of frames (§II-A, §II-B.3-4): :class:`Tracker`
(``_tracker``), which follows the pose pair after pair, warm-starting each estimate from the last,
and its fast warm path on the region where the last pose projects: the region and its view
(``_roi``), its distance maps in reused buffers (``_maps``), the warm estimate (``_warm``), the
pipeline of :meth:`Tracker.track` (``_pipeline``), the fast from-scratch estimate at the label
scale (``_scratch``), its options (``_options``), the frame pairs it accepts (``_input``) and
its warm-up before a live stream (``_warm_up``).
Poses are 4x4 ``T_carm_transducer`` (mm, C-arm frame; docs/tracking.md).
"""

from . import _input, _maps, _options, _pipeline, _roi, _scratch, _tracker, _warm, _warm_up
from ._input import frames_for_views
from ._maps import RegionMaps
from ._options import TrackingConfig
from ._roi import RegionOfInterest, crop_view, region_of_interest
from ._scratch import ScratchEstimator, scaled_pose_options, scratch_estimator
from ._tracker import Tracker
from ._warm import PreparedRegions, RegionEstimator, RegionPlan
from ._warm_up import views_isocentre_mm, warm_up_pair

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_tracker.__all__, *_input.__all__, *_maps.__all__, *_options.__all__,
                              *_pipeline.__all__, *_roi.__all__, *_scratch.__all__, *_warm.__all__,
                              *_warm_up.__all__]))

# the 0.1.0 names, deprecated (CHANGELOG.md)
