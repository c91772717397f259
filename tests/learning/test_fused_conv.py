"""Tests of histostudy.learning.fused_conv: Conv2d -> ReLU in one oneDNN call, the same bits as the
pair run eagerly, and left alone wherever that does not hold."""

import copy

import pytest
import torch
from torch import nn

from histostudy.learning import ConvReLU, FastUNet, UNet, UNetSegmenter, fuse_conv_relu
from histostudy.learning import fused_conv

needs_fusion = pytest.mark.skipif(fused_conv._fused_op() is None, reason="this torch has no fused oneDNN convolution")


def _unet(dtype, input_stride=1):
    torch.manual_seed(1)
    net = UNet(base_width=4, depth=3, input_stride=input_stride).eval()
    return net.to(memory_format=torch.channels_last).to(dtype)


@needs_fusion
@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("input_stride", [1, 2])
def test_fused_network_gives_the_eager_bits(dtype, input_stride):
    eager = _unet(dtype, input_stride)
    fused, n = fuse_conv_relu(copy.deepcopy(eager))
    # two Conv2d -> BatchNorm2d -> ReLU per block: unfolded, nothing is a Conv2d -> ReLU pair
    assert n == 0
    for blocks in (eager.down, eager.dec):
        for j, block in enumerate(blocks):
            blocks[j] = nn.Sequential(*[m for m in block if not isinstance(m, nn.BatchNorm2d)])
    if eager.stem is not None:
        eager.stem = nn.Sequential(eager.stem[0], eager.stem[2])
    fused, n = fuse_conv_relu(copy.deepcopy(eager))
    pairs = 2 * (len(eager.down) + len(eager.dec)) + (eager.stem is not None)
    # a pair whose fused call differs by a bit stays unfused (float32 with channels-last weights:
    # the one-channel first layer, on the machine these tests were written on)
    if n == 0:
        pytest.skip(f"on this CPU no {dtype} pair's fused call gives the eager bits (nothing to compare)")
    assert n <= pairs
    assert sum(isinstance(m, ConvReLU) for m in fused.modules()) == n
    assert sum(isinstance(m, nn.ReLU) for m in fused.modules()) == pairs - n
    x = torch.randn(1, 1, 96, 160).to(dtype).contiguous(memory_format=torch.channels_last)  # not the probe's shape
    with torch.no_grad():
        assert torch.equal(fused.features(x), eager.features(x))


@needs_fusion
def test_fast_unet_fuses_every_pair_and_keeps_the_checkpoint():
    net = UNet(base_width=4, depth=3).eval()
    segmenter = UNetSegmenter(net, scale=0.5)
    fast = FastUNet(segmenter, precision="float32")
    if fast.n_fused_layers == 0:
        pytest.skip("on this CPU no float32 pair's fused call gives the eager bits")
    assert fast.n_fused_layers <= 2 * (4 + 3)
    assert sum(isinstance(m, ConvReLU) for m in fast._net.modules()) == fast.n_fused_layers
    assert isinstance(segmenter.network.down[0][0], nn.Conv2d)  # the checkpoint's network is not modified


def test_only_zero_padded_conv_relu_pairs_are_fused():
    torch.manual_seed(2)
    reflect = nn.Conv2d(3, 4, 3, padding=1, padding_mode="reflect")
    net = nn.Sequential(nn.Sequential(reflect, nn.ReLU()),  # reflect padding: oneDNN pads with zeros
                        nn.Sequential(nn.Conv2d(4, 4, 3, padding=1), nn.Sigmoid()),  # no ReLU after it
                        nn.Sequential(nn.ConvTranspose2d(4, 4, 2, stride=2), nn.ReLU())).eval()
    before = [type(m) for m in net.modules()]
    out, n = fuse_conv_relu(net)
    assert n == 0 and [type(m) for m in out.modules()] == before


def test_nothing_is_fused_without_the_fused_call_or_where_it_differs(monkeypatch):
    def net():
        torch.manual_seed(3)
        return nn.Sequential(nn.Conv2d(2, 4, 3, padding=1), nn.ReLU(inplace=True)).eval()

    monkeypatch.setattr(fused_conv, "_fused_op", lambda: None)
    out, n = fuse_conv_relu(net())
    assert n == 0 and isinstance(out[0], nn.Conv2d) and isinstance(out[1], nn.ReLU)

    def off_by_a_bit(x, weight, bias, *args):
        y = torch.relu(torch.nn.functional.conv2d(x, weight, bias, padding=1))
        return torch.nextafter(y, torch.full_like(y, float("inf")))

    def raises(*args):
        raise RuntimeError("no oneDNN primitive for this layout")

    for op in (off_by_a_bit, raises):
        monkeypatch.setattr(fused_conv, "_fused_op", lambda op=op: op)
        out, n = fuse_conv_relu(net())
        assert n == 0 and isinstance(out[0], nn.Conv2d), op
