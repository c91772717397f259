"""Targeting and treatment (§II-D, §II-E.4): the treatment plan over the zone, its execution with a
journal that resumes where it stopped, the bubble clouds and the post-treatment scan (``plan``);
the prescribed zone and its segmentation in the post-treatment CBCT, §II-E.3-4 (``zone``).
"""

from .plan import (BUBBLE_CLOUD_SIZE_MM, JOURNAL_FORMAT, STUDY_PLAN_INSET_MM, STUDY_PLAN_SPACING_MM, TreatmentPlan,
                   TreatmentRun, bubble_cloud_mask, execute_treatment, load_journal, plan_treatment,
                   post_treatment_phantom, scan_treated_zone)
from .zone import PAPER_ZONE_DIAMETERS_MM, TreatmentZone, ZoneSegmentation, segment_treatment_zone

__all__ = [
    "BUBBLE_CLOUD_SIZE_MM",
    "JOURNAL_FORMAT",
    "PAPER_ZONE_DIAMETERS_MM",
    "STUDY_PLAN_INSET_MM",
    "STUDY_PLAN_SPACING_MM",
    "TreatmentPlan",
    "TreatmentRun",
    "TreatmentZone",
    "ZoneSegmentation",
    "bubble_cloud_mask",
    "execute_treatment",
    "load_journal",
    "plan_treatment",
    "post_treatment_phantom",
    "scan_treated_zone",
    "segment_treatment_zone",
]
