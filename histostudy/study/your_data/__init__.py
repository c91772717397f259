"""Notebook 06, the lab's own data end to end (§II-B to §II-D on a lab's files): :class:`YourDataConfig`,
:func:`prepare`, the part functions, :func:`drive_robot` (the one call that moves the robot, only when
asked) and :func:`record` (``from histostudy.study import your_data as study``). Its helpers, public for
the CLI and the benchmarks: ``lab_dataset`` (the lab-like dataset generated when no lab files are given),
``moving_cine`` (a cine of the robot touring the margin points) and ``moving_cine_live`` (that cine
streamed through the receiver).
"""

from ..section import record
from ._inputs import LabInputs, accepted_focal_errors, plan_table
from ._live import LiveSection, live_section
from ._parameters import SECTION, TITLE, YourDataConfig
from ._section import (
    STATION_OVERLAY_CAPTION,
    CalibrationSection,
    MovingCineSection,
    StationsSection,
    TrackingSection,
    YourDataSetup,
    calibration_section,
    drive_robot,
    focal_error_part,
    inputs_part,
    moving_cine_section,
    prepare,
    stand_ins_part,
    station_overlay,
    stations_section,
    target_part,
    tracking_section,
)

__all__ = [
    "SECTION",
    "STATION_OVERLAY_CAPTION",
    "TITLE",
    "CalibrationSection",
    "LabInputs",
    "LiveSection",
    "MovingCineSection",
    "StationsSection",
    "TrackingSection",
    "YourDataConfig",
    "YourDataSetup",
    "accepted_focal_errors",
    "calibration_section",
    "drive_robot",
    "focal_error_part",
    "inputs_part",
    "live_section",
    "moving_cine_section",
    "plan_table",
    "prepare",
    "record",
    "stand_ins_part",
    "station_overlay",
    "stations_section",
    "target_part",
    "tracking_section",
]
