"""The networks: shapes, the VGG19 configuration against its published size, the regressor head."""

import numpy as np
import pytest
import torch
from torch import nn

from histostudy.learning import build_network
from histostudy.learning.nets.unet import UNet, max_pool_2x2
from histostudy.learning.nets.vgg import VGG19


def _unet_params(c_in, n_classes, w, depth):
    """Parameter count of the U-Net layout, counted independently of the module."""
    def block(a, b):  # two convs without bias, two batch norms (weight + bias)
        return a * b * 9 + b * b * 9 + 4 * b
    widths = [w * 2 ** i for i in range(depth + 1)]
    total = block(c_in, widths[0]) + sum(block(widths[i - 1], widths[i]) for i in range(1, depth + 1))
    for i in range(depth, 0, -1):
        total += widths[i] * widths[i - 1] * 4 + widths[i - 1]  # transposed conv
        total += block(2 * widths[i - 1], widths[i - 1])
    return total + widths[0] * n_classes + n_classes


@pytest.mark.parametrize("shape", [(64, 64), (50, 70), (33, 17)])
def test_unet_keeps_any_input_size(shape):
    torch.manual_seed(0)
    net = UNet(base_width=4, depth=3).eval()
    out = net(torch.randn(2, 1, *shape))
    assert out.shape == (2, 6, *shape)
    assert torch.isfinite(out).all()


def test_unet_layout_and_config():
    net = UNet(in_channels=1, n_classes=6, base_width=8, depth=4)
    assert sum(p.numel() for p in net.parameters()) == _unet_params(1, 6, 8, 4)
    assert build_network(net.config).config == net.config
    with pytest.raises(ValueError, match="base_width"):
        UNet(base_width=0)
    with pytest.raises(ValueError, match=r"x must be \(N, 1, H, W\)"):
        net(torch.zeros(1, 3, 16, 16))


@pytest.mark.parametrize("stride", [2, 4])
def test_strided_unet_reads_and_labels_the_input_grid(stride):
    # the levels run on a grid `stride` times coarser; stem and sub-pixel head bring the logits back
    torch.manual_seed(0)
    net = UNet(base_width=4, depth=2, input_stride=stride).eval()
    assert net.pad_multiple == 4 * stride and net.config["input_stride"] == stride
    for shape in ((64, 64), (50, 70)):
        assert net(torch.randn(1, 1, *shape)).shape == (1, 6, *shape)
    assert net.features(torch.randn(1, 1, 32, 48)).shape == (1, 4, 32 // stride, 48 // stride)
    rebuilt = build_network(net.config)
    rebuilt.load_state_dict(net.state_dict())  # a checkpoint's config rebuilds the same layout
    expected = _unet_params(4, 6, 4, 2) - (4 * 6 + 6)  # the levels, whose first block reads the stem's 4 channels
    expected += 1 * 4 * (2 * stride) ** 2 + 2 * 4  # stem: strided conv without bias, batch norm
    expected += 4 * 6 * stride ** 2 * 9 + 6 * stride ** 2  # sub-pixel head: 3x3 conv to 6 * stride**2
    assert sum(p.numel() for p in net.parameters()) == expected
    # a plain U-Net's layout and config are those of the checkpoints made before input_stride existed
    plain = UNet(base_width=4, depth=2)
    assert "input_stride" not in plain.config and not any(k.startswith("stem") for k in plain.state_dict())
    assert plain.pad_multiple == 4
    for bad in (0, 3, True, 2.0):
        with pytest.raises(ValueError, match="input_stride"):
            UNet(input_stride=bad)


def test_unet_is_local_far_from_a_change():
    # a pixel change affects the logits only within the receptive field, not across the image
    torch.manual_seed(1)
    net = UNet(base_width=2, depth=2).eval()
    x = torch.randn(1, 1, 96, 96)
    y = x.clone()
    y[..., 0, 0] += 10.0
    d = (net(x) - net(y)).abs().amax(dim=1)[0]
    assert d[0, 0] > 0 and d[-1, -1] == 0


def test_vgg19_is_the_16_conv_configuration():
    with torch.device("meta"):
        net = VGG19(width=1.0, n_classes=1000)
    assert net.n_convolutions == 16
    convs = [m for m in net.features if isinstance(m, nn.Conv2d)]
    assert [c.out_channels for c in convs] == [64] * 2 + [128] * 2 + [256] * 4 + [512] * 8
    # torchvision's vgg19 has 20,024,384 feature and 123,642,856 classifier parameters for 3 input
    # channels and 1000 classes; one input channel saves 2 * 64 * 9 weights
    assert sum(p.numel() for p in net.features.parameters()) == 20_024_384 - 2 * 64 * 9
    assert sum(p.numel() for p in net.classifier.parameters()) == 123_642_856


def test_vgg19_regressor_is_sigmoid_then_linear():
    torch.manual_seed(2)
    net = VGG19(width=1 / 16, n_classes=36).eval()
    x = torch.randn(3, 1, 60, 80)
    logits = net(x)
    assert logits.shape == (3, 36)
    net.to_regressor()
    assert net.config["head"] == "regressor"
    with torch.no_grad():
        out = net(x)
        assert out.shape == (3, 2)
        torch.testing.assert_close(out, torch.tensor([[0.0, 1.0]] * 3))  # zero weights, bias (0, 1 rad)
        net.regressor.weight.normal_()
        expected = torch.sigmoid(logits) @ net.regressor.weight.T + net.regressor.bias
        torch.testing.assert_close(net(x), expected)
    with pytest.raises(ValueError, match="already has the regressor"):
        net.to_regressor()
    rebuilt = build_network(net.config)
    rebuilt.load_state_dict(net.state_dict())  # the config rebuilds the same layout


def test_vgg19_cos_sin_regressor_starts_as_the_classes_vote_and_wraps_smoothly():
    """With angle_encoding="cos_sin" the regressor's (c, s) rows start as the classes' (cos, sin):
    a network sure of one class returns that class's azimuth; the azimuth is atan2(s, c), so
    outputs on either side of +-pi are neighbours, not 2 pi apart."""
    from histostudy.learning import wrap_angle
    from histostudy.learning.orientation import hemisphere_angles

    torch.manual_seed(3)
    angles = hemisphere_angles(36)
    net = VGG19(width=1 / 16, n_classes=36, angle_encoding="cos_sin").eval()
    assert net.config["angle_encoding"] == "cos_sin" and "angle_encoding" not in VGG19(width=1 / 16).config
    x = torch.randn(2, 1, 60, 80)
    net.to_regressor(angles)
    with torch.no_grad():
        for k in (0, 7, 20):
            sure = torch.full((1, 36), -30.0)
            sure[0, k] = 30.0  # sigmoid 1 for class k, ~1e-13 for the others
            y = net.regressor(torch.sigmoid(sure))
            az = torch.atan2(y[:, 1], y[:, 0])
            assert abs(float(wrap_angle(az.item() - angles[k, 0]))) < 1e-5
        out = net(x)
        assert out.shape == (2, 2) and torch.all(out[:, 0].abs() <= np.pi)
        # the decoding itself: c = -1 and s = -+1e-3 lie 2e-3 rad apart across the cut at pi
        net.regressor.weight.zero_()
        net.regressor.bias.copy_(torch.tensor([-1.0, 1e-3, 0.7]))
        a = net(x)[0]
        net.regressor.bias.copy_(torch.tensor([-1.0, -1e-3, 0.7]))
        b = net(x)[0]
        assert abs(float(wrap_angle(float(a[0] - b[0])))) < 3e-3 and float(a[1]) == pytest.approx(0.7)
    rebuilt = build_network(net.config)
    rebuilt.load_state_dict(net.state_dict())
    plain = VGG19(width=1 / 16, n_classes=36, angle_encoding="cos_sin").to_regressor()
    torch.testing.assert_close(plain.eval()(x), torch.tensor([[0.0, 1.0]] * 2))  # bias (1, 0, 1): azimuth 0
    with pytest.raises(ValueError, match="class_angles_rad"):
        VGG19(width=1 / 16, n_classes=36, angle_encoding="cos_sin").to_regressor(angles[:5])
    with pytest.raises(ValueError, match="angle_encoding"):
        VGG19(angle_encoding="quaternion")


def test_build_network_rejects_bad_configs():
    with pytest.raises(ValueError, match="'arch'"):
        build_network({"base_width": 4})
    with pytest.raises(ValueError, match="must be 'unet' or 'vgg19'"):
        build_network({"arch": "resnet"})
    with pytest.raises(ValueError, match="does not fit"):
        build_network({"arch": "unet", "widths": 3})
    with pytest.raises(ValueError, match="head"):
        VGG19(head="softmax")


def test_vgg19_batch_norm_variant_matches_torchvisions_vgg19_bn_layout():
    with torch.device("meta"):
        plain = VGG19(width=1.0, n_classes=1000)
        bn = VGG19(width=1.0, n_classes=1000, batch_norm=True)
    norms = [m for m in bn.features if isinstance(m, nn.BatchNorm2d)]
    convs = [m for m in bn.features if isinstance(m, nn.Conv2d)]
    assert len(norms) == len(convs) == 16 and all(c.bias is None for c in convs)
    assert [n.num_features for n in norms] == [c.out_channels for c in convs]
    # a bias-free convolution plus its norm's scale and shift: 16 convolutions' biases become
    # 16 x (2 x channels - channels) extra parameters
    extra = sum(c.out_channels for c in convs)
    assert (sum(p.numel() for p in bn.features.parameters())
            == sum(p.numel() for p in plain.features.parameters()) + extra)
    assert bn.config["batch_norm"] is True and "batch_norm" not in plain.config
    rebuilt = build_network(VGG19(width=1 / 16, batch_norm=True).config)
    assert any(isinstance(m, nn.BatchNorm2d) for m in rebuilt.features)
    with pytest.raises(ValueError, match="batch_norm"):
        VGG19(batch_norm="yes")


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("channels_last", [True, False])
def test_max_pool_2x2_is_max_pool2d(dtype, channels_last):
    torch.manual_seed(6)
    x = torch.randn(2, 5, 12, 18).to(dtype)
    x[0, 0, :2, :2] = 1.5  # ties inside a window
    x[1, 2, 4, 6] = float("nan")  # a NaN takes its window, as max_pool2d's
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    pooled = max_pool_2x2(x)
    reference = torch.nn.functional.max_pool2d(x, 2)
    assert pooled.shape == reference.shape and pooled.dtype == dtype
    assert torch.equal(torch.nan_to_num(pooled, nan=-7.0), torch.nan_to_num(reference, nan=-7.0))
    assert torch.isnan(pooled[1, 2, 2, 3])
    net = UNet(base_width=4, depth=2).eval().to(dtype)
    with torch.no_grad():
        y = torch.randn(1, 1, 16, 24).to(dtype)
        assert torch.equal(net.features(y, pool=max_pool_2x2), net.features(y))
