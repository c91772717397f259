"""The learned stages (§II-B.2 U-Net segmentation, §II-B.4 VGG19 orientation): the networks
(``nets``), their input transforms (``preprocess``), the hybrid synthetic training images
(``datasets``); training: its configuration and stages (``training_config``), losses and validation
metrics (``training_losses``), a teacher's labels as targets (``training_teacher``), the loop
(``training``) and the export (``training_export``);
checkpoints with their provenance (``checkpoints``), the segmenters (``segment``), the U-Net's fast
CPU inference on a region for tracking (``fast_segment``, its fused layers ``fused_conv``, its int8
network ``int8_unet``) and the
orientation angles and sources (``orientation``). The pose estimation above this layer takes a
segmenter and an orientation source.
"""

from . import checkpoints as _checkpoints
from . import datasets as _datasets
from . import fast_segment as _fast_segment
from . import fused_conv as _fused_conv
from . import int8_unet as _int8_unet
from . import nets as _nets
from . import orientation as _orientation
from . import preprocess as _preprocess
from . import segment as _segment
from . import training as _training
from .checkpoints import (
               MODELS_DIR,
               load_checkpoint,
               load_network,
               load_shipped,
               manifest_path,
               save_checkpoint,
               sha256_file,
               shipped_model,
               training_summary,
)
from .datasets import (
               SPLAT_DEVICES,
               SPLIT_CODES,
               HybridFrames,
               HybridImageDataset,
               RenderConfig,
               default_cache_dir,
               flip_angles,
               random_training_pose,
               true_angles,
)
from .fast_segment import FAST_UNET_PRECISIONS, FastUNet, auto_precision, native_bfloat16
from .fused_conv import ConvReLU, fuse_conv_relu, reordering_bound
from .int8_unet import (
               INT8_CALIBRATION_FORMAT,
               INT8_ENGINE,
               Int8UNet,
               calibrate_int8,
               int8_available,
               int8_calibration_path,
               load_int8_calibration,
               save_int8_calibration,
)
from .nets import VGG19, UNet, build_network, max_pool_2x2
from .orientation import (
               N_ORIENTATION_CLASSES,
               LearnedOrientation,
               OracleOrientation,
               OrientationSource,
               angles_from_direction,
               beam_direction_of_pose,
               default_vgg19,
               direction_candidates,
               hemisphere_angles,
               hemisphere_directions,
               orientation_angle_error,
               orientation_class,
               select_direction,
               wrap_angle,
)
from .preprocess import pool_labels, prepare_image
from .segment import (
               OracleSegmenter,
               SegmentationDegradation,
               Segmenter,
               UNetSegmenter,
               default_segmenter,
               keep_largest_component,
               masks_from_labels,
               tracking_segmenter,
)
from .training import (
               SEGMENTATION_LOSSES,
               TRAINING_TABLES,
               FineTuneConfig,
               TrainingConfig,
               TrainingResult,
               angle_loss,
               dice_loss,
               export,
               export_name,
               full_precision_copy,
               half_precision_copy,
               load_teacher,
               run_frame_sets,
               teacher_labeller,
               train,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_nets.__all__, *_checkpoints.__all__, *_datasets.__all__, *_fast_segment.__all__,
                              *_fused_conv.__all__, *_int8_unet.__all__, *_orientation.__all__,
                              *_preprocess.__all__, *_segment.__all__, *_training.__all__]))
