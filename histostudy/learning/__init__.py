"""The learned stages (§II-B.2 U-Net segmentation, §II-B.4 VGG19 orientation): the networks
(``nets``), their input transforms (``preprocess``), the hybrid synthetic training images
(``datasets``); training: its configuration and stages (``training_config``), losses and validation
metrics (``training_losses``), the loop (``training``) and the export (``training_export``);
checkpoints with their provenance (``checkpoints``), the segmenters (``segment``) and the
orientation angles and sources (``orientation``). The pose estimation above this layer takes a
segmenter and an orientation source.
"""

from .nets import UNet, VGG19, build_network
from .checkpoints import (MODELS_DIR, load_checkpoint, load_network, load_shipped, manifest_path, save_checkpoint,
                          sha256_file, shipped_model, training_summary)
from .datasets import (HybridFrames, HybridImageDataset, RenderConfig, SPLIT_CODES, default_cache_dir, flip_angles,
                       random_training_pose, true_angles)
from .orientation import (LearnedOrientation, N_ORIENTATION_CLASSES, OracleOrientation, OrientationSource,
                          angles_from_direction, beam_direction_of_pose, default_vgg19, direction_candidates,
                          hemisphere_angles, hemisphere_directions, orientation_angle_error, orientation_class,
                          select_direction, wrap_angle)
from .preprocess import pool_labels, prepare_image
from .segment import (OracleSegmenter, SegmentationDegradation, Segmenter, UNetSegmenter, default_segmenter,
                      keep_largest_component, masks_from_labels)
from .training import train
from .training_config import FineTuneConfig, SEGMENTATION_LOSSES, TrainingConfig, TrainingResult, run_frame_sets
from .training_export import export
from .training_losses import angle_loss, dice_loss

__all__ = [
    "FineTuneConfig",
    "HybridFrames",
    "HybridImageDataset",
    "LearnedOrientation",
    "MODELS_DIR",
    "N_ORIENTATION_CLASSES",
    "OracleOrientation",
    "OracleSegmenter",
    "OrientationSource",
    "RenderConfig",
    "SEGMENTATION_LOSSES",
    "SPLIT_CODES",
    "SegmentationDegradation",
    "Segmenter",
    "TrainingConfig",
    "TrainingResult",
    "UNet",
    "UNetSegmenter",
    "VGG19",
    "angle_loss",
    "angles_from_direction",
    "beam_direction_of_pose",
    "build_network",
    "default_cache_dir",
    "default_segmenter",
    "default_vgg19",
    "dice_loss",
    "direction_candidates",
    "export",
    "flip_angles",
    "hemisphere_angles",
    "hemisphere_directions",
    "keep_largest_component",
    "load_checkpoint",
    "load_network",
    "load_shipped",
    "manifest_path",
    "masks_from_labels",
    "orientation_angle_error",
    "orientation_class",
    "pool_labels",
    "prepare_image",
    "random_training_pose",
    "run_frame_sets",
    "save_checkpoint",
    "select_direction",
    "sha256_file",
    "shipped_model",
    "train",
    "training_summary",
    "true_angles",
    "wrap_angle",
]
