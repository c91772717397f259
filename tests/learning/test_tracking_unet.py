"""Tests of the shipped U-Net trained for tracking (data/models/unet_tracking; docs/tracking.md, "A
network trained for tracking"): its training table and export name, its checked loading, and its
labels against the shipped U-Net's on a rendered frame."""


import numpy as np
import pytest

from histostudy.cli.study import TRAINING_TABLE_NAMES
from histostudy.imaging import default_biplane, random_background, render_frame
from histostudy.learning import (
    MODELS_DIR,
    TRAINING_TABLES,
    TrainingConfig,
    UNetRunner,
    default_segmenter,
    export_name,
    pool_labels,
    tracking_segmenter,
)
from histostudy.learning.checkpoints import sha256_file
from histostudy.reporting import load_profile
from histostudy.transducer import TransducerModel, pose_facing


def test_the_tracking_table_trains_the_unet_at_quarter_scale_from_the_shipped_weights():
    assert tuple(TRAINING_TABLES) == TRAINING_TABLE_NAMES  # the CLI's choices, without importing torch there
    cfg = TrainingConfig.from_table(TRAINING_TABLES["segmentation_tracking"][0],
                                    load_profile("standard").training["segmentation_tracking"])
    standard = TrainingConfig.from_table("segmentation", load_profile("standard").training["segmentation"])
    assert cfg.task == "segmentation" and cfg.scale == 0.25 and standard.scale == 0.5
    assert cfg.network == standard.network and cfg.crop is None
    shipped = (MODELS_DIR / "unet_standard.safetensors").resolve()
    assert (MODELS_DIR.parent.parent / cfg.init_weights).resolve() == shipped
    assert export_name("segmentation_tracking", "unet", "standard") == "unet_tracking"
    assert export_name("segmentation_tracking", "unet", "paper") == "unet_tracking_paper"
    assert export_name("segmentation", "unet", "standard") == "unet_standard"
    with pytest.raises(ValueError, match="table must be one of .* got 'tracking'"):
        export_name("tracking", "unet", "standard")


def test_the_fine_tracking_table_reads_half_scale_and_runs_its_levels_at_quarter_scale():
    cfg = TrainingConfig.from_table(TRAINING_TABLES["segmentation_tracking_fine"][0],
                                    load_profile("standard").training["segmentation_tracking_fine"])
    standard = TrainingConfig.from_table("segmentation", load_profile("standard").training["segmentation"])
    assert cfg.task == "segmentation" and cfg.scale == standard.scale == 0.5 and cfg.crop is None
    assert cfg.network == {**standard.network, "input_stride": 2} and cfg.init_weights is None
    assert export_name("segmentation_tracking_fine", "unet", "standard") == "unet_tracking_fine"


@pytest.fixture(scope="module")
def networks():
    tracking, shipped = tracking_segmenter(), default_segmenter()
    if tracking is None or shipped is None:
        pytest.skip("the shipped U-Nets (data/models/unet_tracking, unet_standard) are not available")
    return tracking, shipped


def test_the_tracking_unet_loads_at_quarter_scale_with_its_hash_checked(networks):
    """Its manifest's SHA-256 is the file's (load_checkpoint refuses a changed byte: test_checkpoints)."""
    tracking, shipped = networks
    assert tracking.scale == 0.25 and tracking.manifest["input_scale"] == 0.25
    assert tracking.network.config == shipped.network.config
    manifest = tracking.manifest
    assert manifest["sha256"] == sha256_file(MODELS_DIR / "unet_tracking.safetensors")
    assert manifest["init_weights"]["sha256"] == shipped.manifest["sha256"]  # started from the shipped U-Net
    assert manifest["device"] == "cuda" and manifest["validation"]["pixel_accuracy"] > 0.97


def test_tracking_labels_agree_with_the_shipped_network_on_a_rendered_frame(networks):
    """On the tracker's grid (0.25): against the shipped network's labels pooled to it by overlap
    priority, and against the frame's reference labels pooled the same way. Measured on this frame
    (float32): 97.7 % of the pixels and 94.0 % of the foreground (either network's) agree with the
    shipped network; against the reference, 98.4 % / 95.8 % (the shipped network pooled: 97.0 % /
    92.3 %; the shipped weights run at 0.25: 95.6 % / 88.7 %)."""
    tracking, shipped = networks
    rng = np.random.default_rng(11)
    T = pose_facing((0.1, 1.0, 0.2), focal_point_mm=(3.0, -4.0, 6.0), axial_rotation_rad=0.4)
    frame = render_frame(TransducerModel.build(spacing_mm=0.47), T, default_biplane()[0], rng=rng,
                         background=random_background(rng, "phantom"))
    whole = (0, 960, 0, 1240)
    labels = tracking.with_precision("float32").segment_region(frame, whole)
    reference = pool_labels(shipped.with_precision("float32").segment_region(frame, whole), 0.5)
    untrained = UNetRunner(network=shipped.network, scale=0.25).with_precision("float32")
    off_scale = untrained.segment_region(frame, whole)
    assert labels.shape == reference.shape == (240, 310)

    def agreement(a, b):
        fg = (a > 0) | (b > 0)
        return np.mean(a == b), np.mean(a[fg] == b[fg]), int(fg.sum())

    total, foreground, n_foreground = agreement(labels, reference)
    assert n_foreground > 20000
    assert total >= 0.97 and foreground >= 0.93, (total, foreground)
    truth = pool_labels(frame.labels, 0.25)
    total, foreground, _ = agreement(labels, truth)
    assert total >= 0.98 and foreground >= 0.945, (total, foreground)
    # the training is what makes the difference: the shipped weights at 0.25 agree less
    assert foreground > agreement(off_scale, truth)[1] + 0.05
    # every class the shipped network finds, the tracking network finds too
    assert set(np.unique(reference)) <= set(np.unique(labels))
    # labels at 0.5 from the 0.25 network (logits upsampled) have the frame's half-resolution shape
    assert tracking.with_precision("auto").segment_region(frame, (0, 448, 0, 448), upsample=2).shape == (224, 224)
    with pytest.raises(ValueError, match="upsample must be an integer in \\[1, 4\\]"):
        tracking.with_precision("auto").segment_region(frame, (0, 448, 0, 448), upsample=8)
