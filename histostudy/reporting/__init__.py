"""The study run in batch and its report: the profiles (``profiles``), the papermill pipeline
(``pipeline``, stopped cleanly by ``interrupts``), each section's results and the report beside the
paper's values (``report``, ``paper``, ``agreement``, ``twins``, ``headline``, ``markdown``,
``report_html``), the notebooks' figures (``viz``), the sections' content keys (``section_keys``)
and a finished run published (``publish``). Only the command line sits above this layer."""

from .interrupts import StudyInterrupted
from .paper import PAPER, PaperValue
from .pipeline import NotebookFailed, run_study
from .profiles import PROFILE_NAMES, Profile, load_profile
from .publish import publish_run, replace_readme_headline
from .report import SectionWriter, build_report
from .viz import model_scene, plot_frames_with_labels, plot_pose_overlay, targeting_scene

__all__ = [
    # a batch run of the notebooks under a profile
    "run_study",
    "NotebookFailed",
    "StudyInterrupted",
    "Profile",
    "PROFILE_NAMES",
    "load_profile",
    # a section's results, the paper's values and the report
    "SectionWriter",
    "PAPER",
    "PaperValue",
    "build_report",
    # a finished run published in the repository
    "publish_run",
    "replace_readme_headline",
    # the notebooks' figures and 3-D scenes
    "model_scene",
    "plot_frames_with_labels",
    "plot_pose_overlay",
    "targeting_scene",
]
