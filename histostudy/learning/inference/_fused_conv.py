"""A convolution and the ReLU after it in one oneDNN call, for :class:`~.fast_segment.FastUNet`:
:func:`fuse_conv_relu`.

Eager torch runs a U-Net block's ``Conv2d -> ReLU`` as two passes over the activations: the
convolution writes them, the ReLU reads and writes them again. oneDNN, torch's CPU convolution
library, applies the ReLU to each output as the convolution produces it (a "post-op"), so the
second pass disappears: on the shipped U-Net at a tracking region (448 x 448 network pixels,
channels-last bfloat16) its layers took about a fifth less time (docs/tracking.md, "Fifteen pairs
a second on two cores").

The fused call computes the same function up to the order of its float32 sums, not always the
same bits. Eager torch chooses its convolution's implementation per call, by the input's size and
the number of threads (oneDNN for large inputs, its own im2col and matrix product for small ones
or a 1x1 kernel on one thread), and which one sums in which order depends on the CPU's instruction
set: on an AVX-512 machine without AMX the fused and eager float32 layers agree to the bit on a
448 x 448 region and differ by up to 4 ulp on a 96 x 160 one. The contract is therefore a bound:
every output of the fused call lies within

    2 * gamma_k * (|W| * |x| + |b|)  (+ one bfloat16 ulp of the output, in bfloat16)

of the eager pair's, where ``gamma_k = k u / (1 - k u)`` is the forward-error constant of a sum of
``k = in_channels / groups * kernel_rows * kernel_cols + 1`` float32 terms in any order
(``u = 2**-24``; Higham, *Accuracy and Stability of Numerical Algorithms*, §3.1) and ``|W| * |x|``
is the convolution of the absolute values: two orders of the same sum each lie within
``gamma_k * sum |terms|`` of the exact sum, and a ReLU (1-Lipschitz) and a rounding to bfloat16
(monotone) do not widen that beyond the extra ulp. A wrong padding, weight or layout breaks the
bound by orders of magnitude; a reordering cannot. :func:`fuse_conv_relu` checks every pair on a
probe input and leaves it unfused where the fused call is missing from this build of torch,
fails, or breaks the bound. Downstream, the labels are the eager network's except where two
classes' logits are within such rounding of each other (tests/learning/test_fused_conv.py checks
the labels away from those near-ties, on every CPU it runs on).

Inference only (no autograd through the fused call).
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


#: Unit roundoff of float32 (round to nearest), the precision every convolution here accumulates in.
_FLOAT32_UNIT_ROUNDOFF = 2.0 ** -24


def reordering_bound(conv, x):
    """Per output of ``relu(conv(x))`` (a float64 tensor of its shape): how far two evaluations that
    sum the same float32 products in different orders can lie apart, ``2 gamma_k (|W| * |x| + |b|)``,
    plus one bfloat16 ulp of the output where ``x`` is bfloat16 (module docstring). ``conv``: a
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
    probe (channels-last, as :class:`~.fast_segment.FastUNet` runs it)."""
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
