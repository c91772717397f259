"""A convolution and the ReLU after it in one oneDNN call, for :class:`~.fast_segment.FastUNet`:
:func:`fuse_conv_relu`.

Eager torch runs a U-Net block's ``Conv2d -> ReLU`` as two passes over the activations: the
convolution writes them, the ReLU reads and writes them again. oneDNN, torch's CPU convolution
library, applies the ReLU to each output as the convolution produces it (a "post-op"), so the
second pass disappears: on the shipped U-Net at a tracking region (448 x 448 network pixels,
channels-last bfloat16) its layers took 18.8 ms against 23.0 ms on one thread, and 10.6 against
12.5 ms on two (docs/tracking.md, "Fifteen pairs a second on two cores").

The result is the same bits: the convolution is the same oneDNN primitive, and a ReLU commutes with
rounding to bfloat16 or float32 (rounding keeps the sign, and zero stays zero).
:func:`fuse_conv_relu` checks this on a probe input for every pair it fuses, and leaves a pair unfused
where the fused call is missing from this build of torch, fails, or differs by a bit.

Inference only (no autograd through the fused call).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ConvReLU", "fuse_conv_relu"]


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
    """``relu(conv(x))`` of a ``Conv2d`` in one oneDNN call (module docstring); ``x`` as the
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


def _same_bits(conv, relu, fused, probe_rows: int = 24) -> bool:
    """Whether ``fused`` gives ``relu(conv(x))``'s bits on a seeded random probe."""
    generator = torch.Generator().manual_seed(0)
    x = torch.randn((1, conv.in_channels, probe_rows, probe_rows + 8), generator=generator)
    x = x.to(conv.weight.dtype).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        try:
            got = fused(x)
        except RuntimeError:
            return False
        return bool(torch.equal(got, relu(conv(x))))


def fuse_conv_relu(network):
    """``network`` (an inference copy: eval mode, its dtype and memory format set) with each
    ``Conv2d -> ReLU`` pair inside its ``nn.Sequential`` blocks replaced by one :class:`ConvReLU`,
    where the fused call gives the pair's bits (module docstring). Modified in place and returned,
    with the number of pairs fused (0 where this torch has no fused convolution)."""
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
                if _same_bits(layer, layers[i + 1], candidate):
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
