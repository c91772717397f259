"""The lab's own data and equipment (§II-A to §II-D on real hardware): the workflow a lab runs on its
C-arm's files, its CBCT and its robot — pose records and flange poses to a checked hand-eye
calibration, a target in the CBCT to a checked robot move, planned or executed (``workflow``) — and
the frames streamed live from the C-arm over DICOM (``receiver``, biplane pairing in ``pairing``).
The lab-like dataset the project generates to stand in for a lab's files is the study's
(:mod:`histostudy.study.lab_dataset`).
"""

from . import pairing as _pairing, receiver as _receiver, workflow as _workflow
from .pairing import BiplanePairer, DEFAULT_FRAME_INTERVAL_S, Pairing, PlaneFrame, frame_times, posix_seconds
from .receiver import (FrameReceiver, REJECTION_STATUSES, ReceivedFrame, X_RAY_SOP_CLASSES, XRayObjectRejected,
                       decode_xray_object, listen)
from .workflow import (TargetingPlan, calibrate_from_poses, execute_targeting, load_flange_poses, load_pose_record,
                       plan_targeting)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_pairing.__all__, *_receiver.__all__, *_workflow.__all__]))
