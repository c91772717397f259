"""Targeting and treatment (§II-D, §II-E.3-4): the treatment plan over the zone (``plan``), its
execution on the robot, resumable, never firing a point twice (``execution``) with its
transactional, exclusive journal (``journal``: SQLite, an intent and a done per point), the bubble
clouds, the mixed phantom and the post-treatment scan (``bubble_cloud``); the prescribed zone and
its segmentation in the post-treatment CBCT (``zone``, its stages in ``_zone_stages``).
"""

from . import _zone_stages
from . import bubble_cloud as _bubble_cloud
from . import execution as _execution
from . import journal as _journal
from . import plan as _plan
from . import zone as _zone
from .bubble_cloud import BUBBLE_CLOUD_SIZE_MM, bubble_cloud_mask, post_treatment_phantom, scan_treated_zone
from .execution import UNCERTAIN_POLICIES, TreatmentRun, UncertainPointError, execute_treatment, load_journal
from .journal import JOURNAL_FORMAT, JOURNAL_VERSION, JournalError, JournalLockedError, TreatmentJournal
from .plan import STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM, TreatmentPlan, plan_treatment
from .zone import PAPER_ZONE_DIAMETERS_MM, TreatmentZone, ZoneSegmentation, segment_treatment_zone

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_zone_stages.__all__, *_bubble_cloud.__all__, *_execution.__all__, *_journal.__all__,
                              *_plan.__all__, *_zone.__all__]))
