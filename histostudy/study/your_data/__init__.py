"""Notebook 06, the lab's own data end to end (§II-B to §II-D on a lab's files): its transducer from
CAD meshes, the pose at each calibration station, the hand-eye calibration, the pose tracked over a
cine, a target in the CBCT and the planned (or executed) robot move.

Without a lab, :func:`lab_inputs` generates the lab-like dataset of :mod:`.lab_dataset` (DICOM XA
with geometry tags, a NIfTI CBCT, STL meshes, flange poses) and the tables carry the errors
against its synthetic truth; with a lab's files there is no truth and those columns are absent.
Lengths in mm, 4x4 ``T_<to>_<from>`` (docs/architecture.md, "Frames and units").

The section's interface, as notebooks 05 and 07 have theirs: :class:`YourDataConfig` (the
notebook's parameters, checked), :func:`prepare` (the inputs and the transducer model, in a
:class:`YourDataSetup`), then functions returning tables and figures; :func:`drive_robot` is the
one call that plans the move and makes it only when asked (the dry-run guard); :func:`live_section`
streams the cine over DICOM to the receiver on loopback.

Its modules: the parameters (``_parameters``), the inputs and their tables (``_inputs``), the
section's set-up and parts (``_section``), and the live stream (``_live``).
"""

from . import _inputs, _live, _parameters, _section
from ._inputs import (
                      LabInputs,
                      accepted_focal_errors,
                      calibration_table,
                      cine_frame_count,
                      lab_inputs,
                      plan_table,
                      plot_cbct_target,
                      station_poses,
                      target_plan,
                      track_cine,
                      transducer_model,
)
from ._live import LiveFocalFigure, LiveSection, compare_with_tracked, live_section, stream_cine, throughput_table
from ._parameters import RECORDED_PARAMETERS, SECTION_TITLE, YourDataConfig
from ._section import (
                      STATION_OVERLAY_CAPTION,
                      CalibrationSection,
                      MovingCineSection,
                      SectionPart,
                      StationsSection,
                      Timer,
                      TrackingSection,
                      YourDataSetup,
                      calibration_section,
                      drive_robot,
                      focal_error_part,
                      moving_cine_section,
                      plot_cine_focal_error,
                      prepare,
                      record,
                      stand_ins,
                      station_overlay,
                      stations_section,
                      target_part,
                      tracking_section,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_inputs.__all__, *_live.__all__, *_parameters.__all__, *_section.__all__]))
