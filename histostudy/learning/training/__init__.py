"""Training both learned stages (§II-B.2, §II-B.4): the configuration and its tables (``_config``),
the losses (``_losses``), the teacher's labels (``_teacher``), the training loop (``_loop``, its
optimiser and checkpoint tensors in ``_optim``) and half- / full-precision exports of the weights
(``_export``).
"""

from . import _config, _export, _loop, _losses, _optim, _teacher
from ._config import (
                              SEGMENTATION_LOSSES,
                              TRAINING_TABLES,
                              FineTuneConfig,
                              TrainingConfig,
                              TrainingResult,
                              export_name,
                              run_frame_sets,
)
from ._export import export, full_precision_copy, half_precision_copy
from ._loop import train
from ._losses import angle_loss, dice_loss
from ._teacher import load_teacher, teacher_labeller

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_config.__all__, *_export.__all__, *_loop.__all__, *_losses.__all__, *_optim.__all__,
                              *_teacher.__all__]))
