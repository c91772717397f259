"""The oracle segmenter: exact labels, and degradation that reaches the requested recall/precision."""

import numpy as np
import pytest
import torch

from histostudy.imaging import Frame, View, default_biplane, render_labels
from histostudy.learning import (
    OracleSegmenter,
    SegmentationDegradation,
    Segmenter,
    UNetRunner,
    build_network,
    checkpoints,
    default_segmenter,
)
from histostudy.learning.checkpoints import save_checkpoint
from histostudy.learning.nets.unet import UNet
from histostudy.learning.preprocess import prepare_image
from histostudy.learning.segment import masks_from_labels
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, pose_facing


@pytest.fixture(scope="module")
def frame():
    view = default_biplane()[0]
    model = TransducerModel.build(spacing_mm=0.25)
    T = pose_facing((0.1, 1.0, 0.2), (3.0, -4.0, 6.0), 0.4)
    labels = render_labels(model, T, view)
    return Frame(np.zeros(view.shape, np.float32), view, labels=labels, T_carm_transducer=T)


def test_perfect_oracle_returns_the_reference(frame):
    seg = OracleSegmenter()
    assert isinstance(seg, Segmenter)
    out = seg.segment(frame, np.random.default_rng(0))
    assert np.array_equal(out, frame.labels) and out is not frame.labels


def test_named_oracles_of_the_study_configs(frame):
    assert OracleSegmenter.named("none").degradation is None
    table1 = OracleSegmenter.named("table1").degradation
    assert table1 == SegmentationDegradation.paper_table1()
    assert table1.recall[Feature.SCREWS] < 1.0 and table1.precision[Feature.GAPS] < 1.0
    with pytest.raises(ValueError, match=r"degradation must be one of \('table1', 'none'\), got 'tabel1'"):
        OracleSegmenter.named("tabel1")


def _recall_precision(pred, ref, k):
    tp = np.sum((pred == k) & (ref == k))
    return tp / np.sum(ref == k), tp / max(np.sum(pred == k), 1)


def test_degradation_reaches_table1_rates(frame):
    deg = SegmentationDegradation.paper_table1()
    out = OracleSegmenter(deg).segment(frame, np.random.default_rng(1))
    for k in FEATURE_CLASSES:
        recall, precision = _recall_precision(out, frame.labels, k)
        assert recall == pytest.approx(deg.recall[k], abs=0.03), k.name
        # false positives of a higher-priority class may take some of a lower class's pixels
        assert precision == pytest.approx(deg.precision[k], abs=0.05), k.name


def test_lost_thin_feature_pixels_fall_back_to_the_elements(frame):
    deg = SegmentationDegradation(recall={Feature.GAPS: 0.5}, precision={})
    out = OracleSegmenter(deg).segment(frame, np.random.default_rng(2))
    lost = (frame.labels == Feature.GAPS) & (out != Feature.GAPS)
    assert lost.sum() > 0 and np.all(out[lost] == Feature.TRANSDUCER)
    others = frame.labels != Feature.GAPS
    assert np.array_equal(out[others], frame.labels[others])


def test_errors_come_in_blobs_not_salt_and_pepper(frame):
    k = Feature.TRANSDUCER
    def isolated_fraction(sigma):
        deg = SegmentationDegradation(recall={k: 0.9}, precision={}, blob_sigma_px=sigma)
        lost = ((frame.labels == k) & (OracleSegmenter(deg).segment(frame, np.random.default_rng(3)) != k))
        neighbours = sum(np.roll(lost, s, axis=a) for a in (0, 1) for s in (-1, 1))
        return np.mean(neighbours[lost] == 0)
    assert isolated_fraction(3.0) < 0.2 * isolated_fraction(0.0)


def test_degradation_is_seeded(frame):
    seg = OracleSegmenter(SegmentationDegradation.paper_table1())
    a = seg.segment(frame, np.random.default_rng(5))
    assert np.array_equal(a, seg.segment(frame, np.random.default_rng(5)))
    assert not np.array_equal(a, seg.segment(frame, np.random.default_rng(6)))


def test_bad_input(frame):
    with pytest.raises(ValueError, match="recall"):
        SegmentationDegradation(recall={Feature.GAPS: 1.5})
    with pytest.raises(ValueError, match="precision"):
        SegmentationDegradation(precision={Feature.BACKGROUND: 0.9})
    unlabeled = Frame(frame.image, frame.view)
    with pytest.raises(ValueError, match="reference labels"):
        OracleSegmenter().segment(unlabeled, np.random.default_rng(0))
    with pytest.raises(TypeError, match="rng"):
        OracleSegmenter(SegmentationDegradation.paper_table1()).segment(frame, None)
    masks = masks_from_labels(frame.labels)
    assert set(masks) == set(FEATURE_CLASSES) and masks[Feature.SCREWS].dtype == bool



# --- the learned segmenter -------------------------------------------------------------------


class _ThresholdNet(torch.nn.Module):
    """Logits that make class 1 wherever the (standardised) input is positive, else background."""

    def forward(self, x):
        z = torch.zeros(x.shape[0], 6, *x.shape[-2:])
        z[:, 1] = 10.0 * x[:, 0]
        return z


def _step_frame(shape=(64, 96), edge=40):
    view = View.from_gantry(0.0, shape=shape)
    image = np.zeros(shape, np.float32)
    image[:, :edge] = 3.0
    return Frame(image, view)


def test_unet_segmenter_keeps_geometry_at_full_resolution():
    frame = _step_frame()
    seg = UNetRunner(_ThresholdNet(), scale=0.5)
    assert isinstance(seg, Segmenter)
    out = seg.segment(frame, np.random.default_rng(0))
    assert out.shape == frame.shape and out.dtype == np.uint8
    # left of the step: class 1, right of it background; only the pixels at the step may blend
    assert np.all(out[:, :39] == 1) and np.all(out[:, 41:] == 0)


def test_test_time_flips_make_the_labels_mirror_with_the_frame():
    """The mean over the four mirror images is the same set of terms for a frame and for its mirror
    image, so the labels mirror exactly (but near ties, where the sums' rounding may decide)."""
    torch.manual_seed(3)
    net = torch.nn.Conv2d(1, len(Feature), 5, padding=2).eval()  # random, lopsided kernels: labels that vary
    rng = np.random.default_rng(0)
    view = View.from_gantry(0.0, 0.0, shape=(64, 96))
    image = rng.normal(0.0, 1.0, (64, 96)).astype(np.float32)
    plain, flips = UNetRunner(net, scale=0.5), UNetRunner(net, scale=0.5, test_time_flips=True)
    labels = flips.segment(Frame(image, view))
    for axis in (0, 1):
        mirrored = flips.segment(Frame(np.ascontiguousarray(np.flip(image, axis)), view))
        assert np.mean(mirrored != np.flip(labels, axis)) < 1e-3
    assert len(np.unique(labels)) >= 4
    # without the flips a random network is far from mirror-equivariant
    assert np.mean(plain.segment(Frame(np.ascontiguousarray(np.flip(image, 1)), view))
                   != np.flip(plain.segment(Frame(image, view)), 1)) > 0.05
    with pytest.raises(TypeError, match="test_time_flips"):
        UNetRunner(net, test_time_flips="yes")


def test_unet_segmenter_rejects_bad_frames():
    seg = UNetRunner(_ThresholdNet(), scale=0.5)
    with pytest.raises(ValueError, match="scale 0.5"):
        seg.segment(_step_frame(shape=(63, 96)))
    with pytest.raises(TypeError, match="Frame"):
        seg.segment(np.zeros((64, 96), np.float32))


def test_unet_segmenter_from_checkpoint_and_default(tmp_path, monkeypatch):
    torch.manual_seed(0)
    net = UNet(base_width=2, depth=2).eval()
    save_checkpoint(tmp_path / "unet_standard", {f"model.{k}": v for k, v in net.state_dict().items()},
                    net.config, input_scale=0.5)
    frame = _step_frame()
    seg = UNetRunner.load(tmp_path / "unet_standard.safetensors")
    with torch.no_grad():
        small = net(torch.from_numpy(prepare_image(frame.image, 0.5))[None, None])[0].argmax(0).numpy()
    out = seg.segment(frame)
    assert out.shape == frame.shape
    # the full-resolution labels are the upsampled low-resolution arg-max: most agree pixel for pixel
    assert np.mean(out[::2, ::2] == small) > 0.9
    monkeypatch.setattr(checkpoints, "MODELS_DIR", tmp_path)
    assert isinstance(default_segmenter(), UNetRunner)
    monkeypatch.setattr(checkpoints, "MODELS_DIR", tmp_path / "none")
    assert default_segmenter() is None
    v = build_network({"arch": "vgg19", "width": 1 / 32, "head": "regressor"})
    save_checkpoint(tmp_path / "vgg", {f"model.{k}": t for k, t in v.state_dict().items()}, v.config)
    with pytest.raises(ValueError, match="expected a U-Net"):
        UNetRunner.load(tmp_path / "vgg.safetensors")


def test_keep_largest_component_drops_the_smaller_separate_patches():
    from histostudy.learning import keep_largest_component

    labels = np.zeros((60, 80), np.uint8)
    labels[10:40, 10:40] = Feature.TRANSDUCER
    labels[20:25, 10:40] = Feature.GAPS  # inside the body: same component
    labels[50:55, 60:70] = Feature.SCREWS  # apart: dropped
    labels[5, 70] = Feature.TRANSDUCER
    kept = keep_largest_component(labels)
    assert kept.dtype == labels.dtype and kept.shape == labels.shape
    np.testing.assert_array_equal(kept[:45, :45], labels[:45, :45])
    assert not kept[45:, 50:].any() and kept[5, 70] == 0
    # diagonal neighbours belong to the component (8-connectivity)
    labels[40, 40] = Feature.SCREWS
    assert keep_largest_component(labels)[40, 40] == Feature.SCREWS
    single = np.zeros((5, 5), np.uint8)
    np.testing.assert_array_equal(keep_largest_component(single), single)
    with pytest.raises(ValueError, match=r"labels must be a 2-D label image, got shape \(5,\)"):
        keep_largest_component(np.zeros(5, np.uint8))
