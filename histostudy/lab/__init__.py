"""The lab's own data and equipment (§II-A to §II-D on real hardware): the workflow a lab runs on its
C-arm's files, its CBCT and its robot — pose records and flange poses to a checked hand-eye
calibration, a target in the CBCT to a checked robot move, planned or executed (``workflow``; the
flange poses' units judged plausible first, in ``inputs``) — and
the frames streamed live from the C-arm over DICOM: the C-STORE receiver that poses each biplane
pair, the newest first (``receiver``; its pose worker in ``pose_worker``, its counts, timings and
latency percentiles in ``receiver_counts``, its JSON lines in ``pose_lines``, ``histostudy
listen``'s loop and line per pose in ``listening``; who may send it frames, and where it listens,
in ``access``; DICOM over TLS in ``tls``), the received X-ray objects checked and decoded
(``xray_objects``), their biplane pairing by time (``pairing``) and a sender of DICOM objects to it
(``sender``).
The lab-like dataset the project generates to stand in for a lab's files is the study's
(:mod:`histostudy.study.your_data.lab_dataset`).
"""

from . import access as _access
from . import inputs as _inputs
from . import listening as _listening
from . import pairing as _pairing
from . import pose_lines as _pose_lines
from . import receiver as _receiver
from . import receiver_counts as _receiver_counts
from . import sender as _sender
from . import tls as _tls
from . import workflow as _workflow
from . import xray_objects as _xray_objects
from .access import AllowList, AssociationGate, Modality, check_listening_address, load_modalities, parse_allow
from .inputs import FLANGE_DISTANCE_MM, FLANGE_UNIT_SPLIT, check_flange_pose_units
from .listening import listen, pose_summary
from .pairing import DEFAULT_FRAME_INTERVAL_S, BiplanePairer, Pairing, PlaneFrame, frame_times, posix_seconds
from .pose_lines import pose_line
from .receiver import FrameReceiver
from .receiver_counts import COUNT_KEYS, LATENCY_WINDOW, ReceiverCounts
from .sender import SentObject, send_frames, stream_frames
from .tls import TLSConfig
from .workflow import (
               READINGS,
               TargetingPlan,
               accepted_stations,
               calibrate_from_poses,
               execute_targeting,
               load_flange_poses,
               load_pose_record,
               plan_targeting,
               plan_targeting_either_reading,
)
from .xray_objects import (
               REJECTION_STATUSES,
               X_RAY_SOP_CLASSES,
               PendingFrame,
               ReceivedFrame,
               XRayObjectRejected,
               decode_xray_object,
               read_xray_header,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_access.__all__, *_inputs.__all__, *_listening.__all__, *_pairing.__all__,
                              *_pose_lines.__all__, *_receiver.__all__, *_receiver_counts.__all__, *_sender.__all__, *_tls.__all__,
                              *_workflow.__all__, *_xray_objects.__all__]))
