"""A convolution and the ReLU after it in one oneDNN call, within float32 rounding of the eager pair:
:func:`fuse_conv_relu`, for the inference network of :class:`~.runner.UNetRunner`. The bound it
checks each pair against (:func:`reordering_bound`) and why: docs/inference.md, "Fused layers".
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ConvReLU", "fuse_conv_relu", "reordering_bound"]


def _fused_op():
    """torch's fused oneDNN convolution (``torch.ops.mkldnn._convolution_pointwise``), None where
    this build has none."""
    if not torch.backends.mkldnn.is_available():
        return None
    try:
        return torch.ops.mkldnn._convolution_pointwise
    except (AttributeError, RuntimeError):
        return None


class ConvReLU(nn.Module):
    """``relu(conv(x))`` of a ``Conv2d`` in one oneDNN call (docs/inference.md); ``x`` as the
    convolution takes it (its dtype, channels-last or not). ``op``: the fused call
    (:func:`fuse_conv_relu` finds it)."""

    def __init__(self, conv: nn.Conv2d, op):
        super().__init__()
        self.weight = nn.Parameter(conv.weight.detach().clone(), requires_grad=False)
        self.bias = None if conv.bias is None else nn.Parameter(conv.bias.detach().clone(), requires_grad=False)
        self.padding = list(conv.padding)
        self.stride = list(conv.stride)
        self.dilation = list(conv.dilation)
        self.groups = int(conv.groups)
        self._op = op

    def forward(self, x):
        return self._op(x, self.weight, self.bias, self.padding, self.stride, self.dilation, self.groups,
                        "relu", [], "")


#: Unit roundoff of float32 (round to nearest), the precision every convolution here accumulates in.
_FLOAT32_UNIT_ROUNDOFF = 2.0 ** -24


def reordering_bound(conv, x):
    """Per output of ``relu(conv(x))`` (a float64 tensor of its shape): how far two evaluations that
    sum the same float32 products in different orders can lie apart, ``2 gamma_k (|W| * |x| + |b|)``,
    plus one bfloat16 ulp of the output where ``x`` is bfloat16 (docs/inference.md, "Fused layers"). ``conv``: a
    zero-padded ``Conv2d``; ``x``: its input (any memory format)."""
    import torch.nn.functional as F

    k = conv.in_channels // conv.groups * conv.kernel_size[0] * conv.kernel_size[1] + 1
    gamma = k * _FLOAT32_UNIT_ROUNDOFF / (1.0 - k * _FLOAT32_UNIT_ROUNDOFF)
    with torch.no_grad():
        magnitude = F.conv2d(x.double().abs(), conv.weight.double().abs(), None, conv.stride, conv.padding,
                             conv.dilation, conv.groups)
        if conv.bias is not None:
            magnitude = magnitude + conv.bias.double().abs()[None, :, None, None]
        bound = 2.0 * gamma * magnitude
        if x.dtype == torch.bfloat16:
            # an ulp of bfloat16 (8 significant bits) is at most 2**-7 of the value it rounds
            bound = bound + 2.0 ** -7 * (magnitude + bound)
    return bound


def _agrees(conv, relu, fused, probe_rows: int = 24) -> bool:
    """Whether ``fused`` gives ``relu(conv(x))`` within :func:`reordering_bound` on a seeded random
    probe (channels-last, as :class:`~.runner.UNetRunner` runs it)."""
    generator = torch.Generator().manual_seed(0)
    x = torch.randn((1, conv.in_channels, probe_rows, probe_rows + 8), generator=generator)
    x = x.to(conv.weight.dtype).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        try:
            got = fused(x)
        except RuntimeError:
            return False
        expected = relu(conv(x))
        if got.shape != expected.shape or got.dtype != expected.dtype:
            return False
        return bool(((got.double() - expected.double()).abs() <= reordering_bound(conv, x)).all())


def fuse_conv_relu(network):
    """``network`` (an inference copy: eval mode, its dtype and memory format set) with each
    ``Conv2d -> ReLU`` pair inside its ``nn.Sequential`` blocks replaced by one :class:`ConvReLU`,
    where the fused call agrees with the pair within :func:`reordering_bound` on a probe (module
    docstring). Modified in place and returned, with the number of pairs fused (0 where this torch
    has no fused convolution)."""
    op = _fused_op()
    if op is None:
        return network, 0
    n_fused = 0
    for module in list(network.modules()):
        if not isinstance(module, nn.Sequential):
            continue
        layers, fused, i = list(module), [], 0
        while i < len(layers):
            layer = layers[i]
            if (i + 1 < len(layers) and type(layer) is nn.Conv2d and isinstance(layers[i + 1], nn.ReLU)
                    and layer.padding_mode == "zeros"):
                candidate = ConvReLU(layer, op).eval()
                if _agrees(layer, layers[i + 1], candidate):
                    fused.append(candidate)
                    n_fused += 1
                    i += 2
                    continue
            fused.append(layer)
            i += 1
        if len(fused) != len(layers):
            for name in list(module._modules):
                del module._modules[name]
            for k, layer in enumerate(fused):
                module.add_module(str(k), layer)
    return network, n_fused
