"""Tests of histostudy.learning.UNetRunner: the inference network (folded batch norms, channels-last,
on a region) at each precision, checked against the torch checkpoint run eagerly (precision
"reference", the source of truth); docs/inference.md's parity table names these tests."""

import numpy as np
import pytest
import torch

from histostudy.imaging import Frame, default_biplane, random_background, render_frame
from histostudy.learning import PRECISIONS, UNetRunner, default_segmenter
from histostudy.learning.nets.unet import UNet
from histostudy.learning.preprocess import prepare_image
from histostudy.transducer import TransducerModel, pose_facing


def _eager_labels(segmenter, frame):
    """The checkpoint's arg-max at the network's resolution, run as trained (NCHW, batch norms)."""
    with torch.no_grad():
        x = torch.from_numpy(prepare_image(frame.image, segmenter.scale))[None, None]
        return segmenter.network.eval()(x)[0].argmax(dim=0).numpy().astype(np.uint8)


@pytest.fixture(scope="module", params=[1, 2], ids=["plain", "input_stride2"])
def random_unet(request):
    torch.manual_seed(0)
    net = UNet(base_width=4, depth=3, input_stride=request.param).eval()
    with torch.no_grad():  # batch-norm statistics other than the identity, so that folding matters
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
    return UNetRunner(net, scale=0.5)


def test_folded_channels_last_network_gives_the_eager_logits(random_unet):
    fast = random_unet.with_precision("float32")
    x = torch.randn(1, 1, 64, 96)
    with torch.no_grad():
        reference = random_unet.network(x)
        out = fast._forward(x.contiguous(memory_format=torch.channels_last))
    torch.testing.assert_close(out, reference, rtol=1e-4, atol=1e-4)
    assert random_unet.network.down[0][1].__class__ is torch.nn.BatchNorm2d  # the checkpoint is untouched
    assert (fast.scale, fast.stride_px, fast.network_stride_px) == (0.5, 2, 16 * random_unet.network.input_stride)


def test_region_labels_are_the_network_resolution_labels_of_the_box(random_unet):
    view = default_biplane()[0].scaled(0.25)  # 240 x 310
    image = np.random.default_rng(1).standard_normal(view.shape).astype(np.float32)
    frame = Frame(image, view)
    fast = random_unet.with_precision("float32")
    full = fast.segment_region(frame, (0, 240, 0, 310))
    np.testing.assert_array_equal(full, _eager_labels(random_unet, frame))
    part = fast.segment_region(frame, (32, 160, 64, 224))
    assert part.shape == (64, 80) and part.dtype == np.uint8


def test_upsampled_region_labels_are_the_interpolated_logits_arg_max_and_reuse_the_features(random_unet,
                                                                                          monkeypatch):
    from torch.nn import functional as F

    view = default_biplane()[0].scaled(0.25)
    frame = Frame(np.random.default_rng(2).standard_normal(view.shape).astype(np.float32), view)
    fast = random_unet.with_precision("float32")
    box = (32, 224, 64, 288)
    logits = fast._logits(frame, box)
    reference = F.interpolate(logits[None], scale_factor=2, mode="bilinear", align_corners=False)[0]
    # the edge-only interpolation gives the full interpolation's arg-max, pixel for pixel
    np.testing.assert_array_equal(fast.segment_region(frame, box, 2), reference.argmax(dim=0).numpy())
    runs = []
    forward = fast._network_features
    monkeypatch.setattr(fast, "_network_features", lambda x: runs.append(1) or forward(x))
    coarse = fast.segment_region(frame, box)  # the same box of the same frame: no second forward pass
    again = fast.segment_region(frame, box, 2)
    assert runs == [] and coarse.shape == (96, 112) and again.shape == (192, 224)
    copy = Frame(frame.image.copy(), view)  # another frame (or a new image) runs the network again
    np.testing.assert_array_equal(fast.segment_region(copy, box), coarse)
    assert runs == [1]


@pytest.fixture(scope="module")
def shipped_and_frame():
    segmenter = default_segmenter()
    if segmenter is None:
        pytest.skip("the shipped U-Net (data/models/unet_standard) is not available")
    view = default_biplane()[0]
    rng = np.random.default_rng(11)
    T = pose_facing((0.1, 1.0, 0.2), focal_point_mm=(3.0, -4.0, 6.0), axial_rotation_rad=0.4)
    frame = render_frame(TransducerModel.build(spacing_mm=0.47), T, view, rng=rng,
                         background=random_background(rng, "phantom"))
    return segmenter, frame


@pytest.mark.parametrize("precision", ["auto", "float32", "int8"])
def test_fast_labels_agree_with_the_checkpoint_on_a_rendered_frame(shipped_and_frame, precision):
    """The fast path's labels against the torch checkpoint run eagerly in float32, at the network's
    resolution: on the whole frame, and on a tracking region (the crop changes the context near its
    edges). "auto" is bfloat16 on a CPU with native bfloat16; "int8" the stored calibration's network."""
    segmenter, frame = shipped_and_frame
    fast = segmenter.with_precision(precision)
    reference = _eager_labels(segmenter, frame)
    whole = fast.segment_region(frame, (0, 960, 0, 1240))
    assert whole.shape == reference.shape == (480, 620)
    assert np.mean(whole == reference) >= 0.999
    foreground = (whole > 0) | (reference > 0)
    assert foreground.sum() > 10000 and np.mean(whole[foreground] == reference[foreground]) >= 0.995
    box = (64, 896, 128, 1152)
    region = fast.segment_region(frame, box)
    in_box = reference[32:448, 64:576]
    assert region.shape == in_box.shape
    assert np.mean(region == in_box) >= 0.99
    foreground = (region > 0) | (in_box > 0)
    assert np.mean(region[foreground] == in_box[foreground]) >= 0.98


@pytest.mark.parametrize("precision", ["auto", "float32", "int8"])
def test_full_frame_labels_are_the_checkpoints_upsampled_labels(shipped_and_frame, precision):
    """UNetRunner.segment at a precision against the reference's, which upsamples
    all six logit channels before the arg-max: the same labels in float32, 99.9 % in bfloat16 and int8."""
    segmenter, frame = shipped_and_frame
    fast = segmenter.with_precision(precision)
    reference = segmenter.segment(frame)
    labels = fast.segment(frame, np.random.default_rng(0))
    assert labels.shape == frame.shape and labels.dtype == np.uint8
    if fast.precision == "float32":
        assert np.mean(labels == reference) >= 0.99999
    foreground = (labels > 0) | (reference > 0)
    assert np.mean(labels == reference) >= 0.999 and np.mean(labels[foreground] == reference[foreground]) >= 0.995


def test_bad_input_is_refused_naming_the_argument(random_unet):
    fast = random_unet.with_precision("auto")
    view = default_biplane()[0].scaled(0.25)
    frame = Frame(np.zeros(view.shape, np.float32), view)
    with pytest.raises(ValueError, match=r"box must be 4 integers"):
        fast.segment_region(frame, (0, 64, 0))
    with pytest.raises(ValueError, match=r"must lie in the frame"):
        fast.segment_region(frame, (0, 400, 0, 64))
    with pytest.raises(ValueError, match=r"multiples of 2 frame pixels"):
        fast.segment_region(frame, (1, 65, 0, 64))
    with pytest.raises(TypeError, match="frame must be"):
        fast.segment_region(frame.image, (0, 64, 0, 64))
    with pytest.raises(TypeError, match="frame must be"):
        fast.segment(frame.image)
    odd = default_biplane()[0].scaled(0.25)
    odd_frame = Frame(np.zeros((239, 310), np.float32), type(odd).from_matrix(odd.P, (239, 310), odd.pixel_mm))
    with pytest.raises(ValueError, match="not divisible by 1/scale = 2"):
        fast.segment(odd_frame)
    with pytest.raises(ValueError, match="precision must be one of"):
        random_unet.with_precision("float16")
    with pytest.raises(ValueError, match="test_time_flips runs with precision 'reference' only"):
        UNetRunner(random_unet.network, "float32", test_time_flips=True)
    with pytest.raises(ValueError, match="without test-time flips"):
        UNetRunner(random_unet.network, test_time_flips=True).segment_region(frame, (0, 64, 0, 64))


def test_the_reference_runs_the_checkpoint_as_trained_on_frames_and_regions(random_unet):
    """Precision "reference" (the default, and default_segmenter's) runs the network itself: its
    region labels are the eager network's on the box; nothing is folded or fused."""
    assert PRECISIONS[0] == random_unet.precision == "reference" and random_unet.n_fused_layers == 0
    view = default_biplane()[0].scaled(0.25)
    frame = Frame(np.random.default_rng(4).standard_normal(view.shape).astype(np.float32), view)
    np.testing.assert_array_equal(random_unet.segment_region(frame, (0, 240, 0, 310)),
                                  _eager_labels(random_unet, frame))
    assert random_unet.segment(frame).shape == frame.shape
    assert "reference" in repr(random_unet) and random_unet.with_precision("float32").precision == "float32"


def test_the_default_segmenter_is_the_reference():
    segmenter = default_segmenter()
    if segmenter is None:
        pytest.skip("the shipped U-Net (data/models/unet_standard) is not available")
    assert isinstance(segmenter, UNetRunner) and segmenter.precision == "reference"
    assert not segmenter.test_time_flips and segmenter.manifest["sha256"]


@pytest.mark.parametrize("precision", ["reference", "float32"])
def test_a_runner_pickles_to_one_that_gives_the_same_labels(random_unet, precision):
    """Sweeps send the runner to their workers and key their cache on its pickle: the copy is
    rebuilt from the network and precision, without the recent features, and gives the same labels."""
    import pickle

    runner = random_unet.with_precision(precision)
    view = default_biplane()[0].scaled(0.25)
    frame = Frame(np.random.default_rng(5).standard_normal(view.shape).astype(np.float32), view)
    before = runner.segment_region(frame, (0, 240, 0, 310))  # fills the recent features
    copy = pickle.loads(pickle.dumps(runner))
    assert copy._recent == {} and copy.precision == precision
    np.testing.assert_array_equal(copy.segment_region(frame, (0, 240, 0, 310)), before)
    assert runner._recent  # the original keeps its own


def test_the_channel_arg_max_is_torch_s_with_its_ties():
    """The labels' arg-max over the classes (a running maximum) is Tensor.argmax's, ties to the
    first class included: logits rounded to a coarse grid tie often."""
    from histostudy.learning.inference.runner import _channel_argmax

    logits = torch.round(torch.randn(6, 37, 53, generator=torch.Generator().manual_seed(3)) * 2) / 2
    expected = logits.argmax(dim=0).to(torch.uint8).numpy()
    assert (logits == logits.max(dim=0).values).sum(dim=0).gt(1).any()  # ties present
    labels = _channel_argmax(logits)
    assert labels.dtype == np.uint8
    np.testing.assert_array_equal(labels, expected)
