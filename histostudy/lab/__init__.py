"""The lab's own data and equipment (§II-A to §II-D on real hardware): the workflow on a lab's C-arm
files, CBCT and robot (``workflow``: pose records and flange poses to a checked hand-eye
calibration, a target to a checked robot move; ``inputs``: the flange poses' units), and the live
frames over DICOM (``receiver``: the C-STORE receiver that poses each biplane pair; ``listening``:
``histostudy listen``'s loop; ``access``, ``tls``: who may send; ``sender``: a sender).
"""

from .access import AllowList, Modality, load_modalities, parse_allow
from .inputs import check_flange_pose_units
from .listening import listen
from .receiver import FrameReceiver, ReceiverConfig
from .sender import SentObject, send_frames, stream_frames
from .tls import TLSConfig
from .workflow import (
    TargetingPlan,
    accepted_stations,
    calibrate_from_poses,
    execute_targeting,
    load_flange_poses,
    load_pose_record,
    plan_targeting,
    plan_targeting_either_reading,
)
from .xray_objects import REJECTION_STATUSES, VIEW_MATCH_TOLERANCE_MM

__all__ = [
    # the live receiver and its senders
    "FrameReceiver", "ReceiverConfig", "listen", "AllowList", "Modality", "load_modalities", "parse_allow",
    "TLSConfig", "REJECTION_STATUSES", "VIEW_MATCH_TOLERANCE_MM", "send_frames", "stream_frames", "SentObject",
    # the workflow on the lab's files
    "load_pose_record", "load_flange_poses", "check_flange_pose_units", "accepted_stations", "calibrate_from_poses",
    "TargetingPlan", "plan_targeting", "plan_targeting_either_reading", "execute_targeting",
]
