"""The learned stages (§II-B.2 U-Net segmentation, §II-B.4 VGG19 orientation): the networks
(``nets``), their input transforms (``preprocess``), the hybrid training images (``datasets``), the
training (``training``), checkpoints (``checkpoints``), the segmenters (``segment``), the one way to
run the U-Net (``inference``) and the orientation sources (``orientation``). Docs:
docs/learned-stages.md, docs/training.md, docs/inference.md.
"""

from .checkpoints import MODELS_DIR, shipped_model, training_summary
from .datasets import HybridFrames, RenderConfig, default_cache_dir
from .inference import PRECISIONS, UNetRunner, native_bfloat16
from .nets import build_network
from .orientation import (
    LearnedOrientation,
    OracleOrientation,
    OrientationSource,
    angles_from_direction,
    beam_direction_of_pose,
    default_vgg19,
    direction_candidates,
    orientation_angle_error,
    select_direction,
    wrap_angle,
)
from .preprocess import pool_labels
from .segment import (
    OracleSegmenter,
    SegmentationDegradation,
    Segmenter,
    default_segmenter,
    keep_largest_component,
    tracking_segmenter,
)
from .training import (
    TRAINING_TABLES,
    TrainingConfig,
    export,
    export_name,
    full_precision_copy,
    half_precision_copy,
    prerender_run,
    run_frame_sets,
    train,
)

__all__ = [
    # segmentation (§II-B.2)
    "Segmenter", "OracleSegmenter", "SegmentationDegradation", "default_segmenter", "tracking_segmenter",
    "keep_largest_component", "pool_labels", "UNetRunner", "PRECISIONS", "native_bfloat16",
    # orientation (§II-B.4)
    "OrientationSource", "OracleOrientation", "LearnedOrientation", "default_vgg19", "direction_candidates",
    "select_direction", "angles_from_direction", "beam_direction_of_pose", "orientation_angle_error", "wrap_angle",
    # training data, training and checkpoints
    "HybridFrames", "RenderConfig", "default_cache_dir", "build_network", "TrainingConfig", "TRAINING_TABLES",
    "train", "export", "export_name", "run_frame_sets", "prerender_run", "full_precision_copy", "half_precision_copy",
    "MODELS_DIR", "shipped_model", "training_summary",
]
