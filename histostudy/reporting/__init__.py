"""The study run in batch and its report: the profiles (``profiles``: smoke, standard, paper), the
papermill pipeline (``pipeline``), the report that sets each measured value beside the paper's
(``report``, with the paper's values in ``paper``) and the notebooks' figures and 3-D scenes
(``viz``). The top layer: nothing below imports it.
"""

from .paper import PAPER, PaperValue, paper_value
from .pipeline import NotebookFailed, discover_notebooks, run_study, select_notebooks
from .profiles import PROFILE_NAMES, Profile, load_profile
from .report import RESULTS_FILE, SectionWriter, build_report, format_measure, load_section, results_coverage
from .viz import FEATURE_COLOURS, label_rgb, model_scene, plot_frames_with_labels, plot_pose_overlay, targeting_scene

__all__ = [
    "FEATURE_COLOURS",
    "NotebookFailed",
    "PAPER",
    "PROFILE_NAMES",
    "PaperValue",
    "Profile",
    "RESULTS_FILE",
    "SectionWriter",
    "build_report",
    "discover_notebooks",
    "format_measure",
    "label_rgb",
    "load_profile",
    "load_section",
    "model_scene",
    "paper_value",
    "plot_frames_with_labels",
    "plot_pose_overlay",
    "results_coverage",
    "run_study",
    "select_notebooks",
    "targeting_scene",
]
