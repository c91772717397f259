"""Tests of histostudy.learning.inference._fused_conv: Conv2d -> ReLU in one oneDNN call, within float32
rounding of the pair run eagerly (the bound of reordering_bound) on every shape, the same labels
away from near-ties, and left alone wherever that does not hold."""

import copy

import pytest
import torch
from torch import nn

from histostudy.learning import UNetRunner
from histostudy.learning.inference import _fused_conv as fused_conv
from histostudy.learning.inference._fused_conv import ConvReLU, fuse_conv_relu, reordering_bound
from histostudy.learning.nets.unet import UNet

needs_fusion = pytest.mark.skipif(fused_conv._fused_op() is None, reason="this torch has no fused oneDNN convolution")


def _unet(dtype, input_stride=1):
    torch.manual_seed(1)
    net = UNet(base_width=4, depth=3, input_stride=input_stride).eval()
    return net.to(memory_format=torch.channels_last).to(dtype)


def _without_batch_norms(net):
    """``net`` with its batch normalisations dropped, so that its blocks hold Conv2d -> ReLU pairs."""
    for blocks in (net.down, net.dec):
        for j, block in enumerate(blocks):
            blocks[j] = nn.Sequential(*[m for m in block if not isinstance(m, nn.BatchNorm2d)])
    if net.stem is not None:
        net.stem = nn.Sequential(net.stem[0], net.stem[2])
    return net


def _pair_inputs(eager, x):
    """Each Conv2d of ``eager`` followed by a ReLU in its block, with the input it gets on ``x``."""
    pairs, hooks = [], []
    for block in eager.modules():
        if isinstance(block, nn.Sequential):
            layers = list(block)
            for conv, after in zip(layers, layers[1:]):
                if type(conv) is nn.Conv2d and isinstance(after, nn.ReLU):
                    hooks.append(conv.register_forward_pre_hook(lambda m, args: pairs.append((m, args[0]))))
    with torch.no_grad():
        eager.features(x)
    for hook in hooks:
        hook.remove()
    return pairs


@needs_fusion
@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("input_stride", [1, 2])
def test_fused_layers_agree_with_the_eager_pairs_within_the_bound_on_other_shapes(dtype, input_stride):
    eager = _unet(dtype, input_stride)
    fused, n = fuse_conv_relu(copy.deepcopy(eager))
    # two Conv2d -> BatchNorm2d -> ReLU per block: unfolded, nothing is a Conv2d -> ReLU pair
    assert n == 0
    eager = _without_batch_norms(eager)
    fused, n = fuse_conv_relu(copy.deepcopy(eager))
    pairs = 2 * (len(eager.down) + len(eager.dec)) + (eager.stem is not None)
    if n == 0:
        # the bfloat16 fused call is refused below AVX-512 (oneDNN: "bf16 path needs avx512bw ...")
        pytest.skip(f"on this CPU no {dtype} pair has a fused call that keeps the bound (nothing to compare)")
    assert n <= pairs
    assert sum(isinstance(m, ConvReLU) for m in fused.modules()) == n
    assert sum(isinstance(m, nn.ReLU) for m in fused.modules()) == pairs - n
    fused_layers = [m for m in fused.modules() if isinstance(m, ConvReLU)]
    # Shapes other than the probe's, on both sides of eager torch's switch between oneDNN and its
    # own im2col path (an input of 20,480 values), and one and two threads.
    threads = torch.get_num_threads()
    try:
        for n_threads in (1, 2):
            torch.set_num_threads(n_threads)
            for rows, cols in ((96, 160), (224, 224)):
                generator = torch.Generator().manual_seed(rows + n_threads)
                x = torch.randn((1, 1, rows, cols), generator=generator).to(dtype)
                x = x.contiguous(memory_format=torch.channels_last)
                checked = 0
                for conv, layer_input in _pair_inputs(eager, x):
                    twin = next((f for f in fused_layers if torch.equal(f.weight, conv.weight)), None)
                    if twin is None:
                        continue  # left unfused
                    with torch.no_grad():
                        gap = (twin(layer_input).double() - torch.relu(conv(layer_input)).double()).abs()
                    bound = reordering_bound(conv, layer_input)
                    assert bool((gap <= bound).all()), (rows, cols, n_threads, float((gap - bound).max()))
                    checked += 1
                assert checked == n
    finally:
        torch.set_num_threads(threads)


@needs_fusion
@pytest.mark.parametrize("input_stride", [1, 2])
def test_fused_network_gives_the_eager_labels_away_from_near_ties(input_stride):
    eager = _without_batch_norms(_unet(torch.float32, input_stride))
    fused, n = fuse_conv_relu(copy.deepcopy(eager))
    if n == 0:
        pytest.skip("on this CPU no float32 pair has a fused call that keeps the bound")
    x = torch.randn((1, 1, 96, 160), generator=torch.Generator().manual_seed(7))
    x = x.contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        reference, got = eager(x)[0], fused(x)[0]
    torch.testing.assert_close(got, reference, rtol=1e-5, atol=1e-5 * float(reference.abs().max()))
    top2 = reference.topk(2, dim=0).values
    clear = (top2[0] - top2[1]) > 1e-4 * float(reference.abs().max())
    assert float(clear.float().mean()) > 0.99
    assert torch.equal(got.argmax(dim=0)[clear], reference.argmax(dim=0)[clear])


def test_the_bound_holds_for_a_reordered_sum_and_fails_for_a_wrong_layer():
    torch.manual_seed(4)
    conv = nn.Conv2d(16, 8, 3, padding=1).eval()
    x = torch.randn(1, 16, 20, 24)
    with torch.no_grad():
        expected = torch.relu(conv(x))
        # the same sum, accumulated in float32 input channel by input channel in reverse order
        reordered = conv.bias[None, :, None, None].expand_as(expected).clone()
        for c in reversed(range(16)):
            reordered += nn.functional.conv2d(x[:, c:c + 1], conv.weight[:, c:c + 1], None, padding=1)
        reordered = torch.relu(reordered)
        bound = reordering_bound(conv, x)
        assert not torch.equal(reordered, expected)  # the orders differ in the last bits ...
        assert bool(((reordered.double() - expected.double()).abs() <= bound).all())  # ... within the bound
        # a bound of rounding, not of arithmetic: a one-pixel shift (a wrong padding) is far outside it
        shifted = torch.relu(nn.functional.conv2d(x, conv.weight, conv.bias, padding=(1, 2)))[..., :24]
        assert float(((shifted.double() - expected.double()).abs() / bound.clamp_min(1e-30)).max()) > 1e3
        bf16 = reordering_bound(conv.to(torch.bfloat16), x.to(torch.bfloat16))
        assert bool((bf16 > bound).all())  # one bfloat16 ulp of the output more


@needs_fusion
def test_the_inference_network_fuses_every_pair_and_keeps_the_checkpoint():
    net = UNet(base_width=4, depth=3).eval()
    segmenter = UNetRunner(net, scale=0.5)
    fast = segmenter.with_precision("float32")
    if fast.n_fused_layers == 0:
        pytest.skip("on this CPU no float32 pair has a fused call that keeps the bound")
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


def test_nothing_is_fused_without_the_fused_call_or_where_it_breaks_the_bound(monkeypatch):
    def net():
        torch.manual_seed(3)
        return nn.Sequential(nn.Conv2d(2, 4, 3, padding=1), nn.ReLU(inplace=True)).eval()

    monkeypatch.setattr(fused_conv, "_fused_op", lambda: None)
    out, n = fuse_conv_relu(net())
    assert n == 0 and isinstance(out[0], nn.Conv2d) and isinstance(out[1], nn.ReLU)

    def eager_pair(x, weight, bias, *args):
        return torch.relu(torch.nn.functional.conv2d(x, weight, bias, padding=1))

    def off_by_an_ulp(*args):  # another summation order: within the bound, fused
        y = eager_pair(*args)
        return torch.nextafter(y, torch.full_like(y, float("inf")))

    def off_by_a_thousandth(*args):  # a wrong weight or scale: outside it
        return eager_pair(*args) * 1.001

    def unpadded(x, weight, bias, *args):  # a wrong padding: another shape
        return torch.relu(torch.nn.functional.conv2d(x, weight, bias))

    def raises(*args):
        raise RuntimeError("no oneDNN primitive for this layout")

    for op, expected in ((eager_pair, 1), (off_by_an_ulp, 1), (off_by_a_thousandth, 0), (unpadded, 0), (raises, 0)):
        monkeypatch.setattr(fused_conv, "_fused_op", lambda op=op: op)
        out, n = fuse_conv_relu(net())
        assert n == expected and isinstance(out[0], ConvReLU if expected else nn.Conv2d), op
