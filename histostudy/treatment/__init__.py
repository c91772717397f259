"""Targeting and treatment (§II-D, §II-E.3-4): the treatment plan over the zone (``plan``), its
resumable execution on the robot, never firing a point twice (``execution``, over the SQLite
``journal``), the bubble clouds and the post-treatment scan (``bubble_cloud``), and the prescribed
zone and its segmentation in the post-treatment CBCT (``zone``, its stages in ``_zone_stages``)."""

from .bubble_cloud import scan_treated_zone
from .execution import execute_treatment
from .plan import STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM, plan_treatment
from .zone import TreatmentZone, ZoneSegmentation, segment_treatment_zone

__all__ = [
    "STUDY_PLAN_INSET_MM",
    "STUDY_PLAN_SPACING_MM",
    "TreatmentZone",
    "ZoneSegmentation",
    "execute_treatment",
    "plan_treatment",
    "scan_treated_zone",
    "segment_treatment_zone",
]
