"""Training both learned stages (§II-B.2, §II-B.4): the configuration and its tables (``_config``),
the losses (``_losses``), a teacher's labels (``_teacher``), the frames rendered beforehand
(``_frames``), the loop (``_loop``, its optimiser and checkpoint tensors in ``_optim``) and the
half- / full-precision exports (``_export``). Docs: docs/training.md.
"""

from ._config import TRAINING_TABLES, FineTuneConfig, TrainingConfig, export_name, run_frame_sets
from ._export import export, full_precision_copy, half_precision_copy
from ._frames import prerender_run
from ._loop import train

__all__ = ["TRAINING_TABLES", "FineTuneConfig", "TrainingConfig", "export", "export_name", "full_precision_copy",
           "half_precision_copy", "prerender_run", "run_frame_sets", "train"]
