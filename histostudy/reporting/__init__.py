"""The study run in batch and its report: the profiles (``profiles``: smoke, standard, paper), the
papermill pipeline (``pipeline``), stopped cleanly by SIGINT or SIGTERM (``interrupts``), the report
that sets each measured value beside the paper's (``report``, with the paper's values in ``paper``,
the agreement rule in ``agreement``, every paper result's twin in ``twins``, the first screen in
``headline``, Markdown escaping in ``markdown`` and the self-contained page in ``report_html``) and
the notebooks' figures and 3-D scenes (``viz``, the targeting scene's parts in ``_targeting_parts``),
the sections' content keys that let a rerun keep what did not change (``section_keys``) and a
finished run published in the repository with its staleness check (``publish``).
The top layer: nothing below imports it.
"""

from . import _targeting_parts
from . import agreement as _agreement
from . import headline as _headline
from . import interrupts as _interrupts
from . import markdown as _markdown
from . import paper as _paper
from . import pipeline as _pipeline
from . import profiles as _profiles
from . import publish as _publish
from . import report as _report
from . import report_html as _report_html
from . import section_keys as _section_keys
from . import twins as _twins
from . import viz as _viz
from .agreement import AGREES, DIFFERS, FAR_OFF, FAR_OFF_SD, NOT_JUDGED, Agreement, judge
from .headline import (
               CONTENTS_ANCHOR,
               HEADLINE_ANCHOR,
               HEADLINE_KEYS,
               SOFTWARE_ANCHOR,
               contents_markdown,
               headline_markdown,
               profile_banner,
               run_facts,
)
from .interrupts import StudyInterrupted, remove_temporaries, signals_interrupt, stop_kernels
from .markdown import Markdown, dataframe_markdown, md_code, md_escape, md_link, md_table
from .paper import PAPER, PaperValue, paper_value
from .pipeline import NotebookFailed, discover_notebooks, run_study, select_notebooks
from .profiles import PROFILE_NAMES, Profile, load_profile, notebook_parameters, validate_profile
from .publish import (
               PUBLISHED_SUFFIXES,
               README_HEADLINE_BEGIN,
               README_HEADLINE_END,
               publish_run,
               readme_headline,
               replace_readme_headline,
               stale_parameters,
)
from .report import RESULTS_FILE, SectionWriter, build_report, format_measure, load_section
from .report_html import CARD_COLUMNS, render_html
from .section_keys import (
               KEY_FILE,
               SectionKey,
               changed_parts,
               code_digest,
               estimate_seconds,
               kept_section,
               record_key,
               remove_key,
               section_key,
               stored_key,
               weights_digest,
)
from .twins import (
               RESULT_KEYS,
               TWINS_ANCHOR,
               TWINS_HEADING,
               results_coverage,
               section_anchor,
               stand_ins_anchor,
               status_markdown,
               twins_markdown,
)
from .viz import FEATURE_COLOURS, label_rgb, model_scene, plot_frames_with_labels, plot_pose_overlay, targeting_scene

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_targeting_parts.__all__, *_agreement.__all__, *_headline.__all__,
                              *_interrupts.__all__, *_markdown.__all__, *_paper.__all__, *_pipeline.__all__,
                              *_profiles.__all__, *_publish.__all__, *_report.__all__, *_report_html.__all__,
                              *_section_keys.__all__, *_twins.__all__,
                              *_viz.__all__]))
