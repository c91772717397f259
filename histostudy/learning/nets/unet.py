"""U-Net for feature segmentation (paper §II-B.2; Ronneberger et al. 2015), a plain torch module, with
an optional strided stem and sub-pixel head (``input_stride``) for the tracker's regions
(docs/training.md, "The networks").
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["UNet", "max_pool_2x2"]


def _block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
    )


def max_pool_2x2(x: torch.Tensor) -> torch.Tensor:
    """``F.max_pool2d(x, 2)`` of an ``(N, C, H, W)`` tensor with even ``H`` and ``W``, as the maximum of
    its four strided quarters: the same values, faster on a CPU for channels-last activations
    (docs/tracking.md, "Fifteen pairs a second"), channels-last out. For inference: on ties its
    gradient is not max-pooling's."""
    return torch.maximum(torch.maximum(x[..., ::2, ::2], x[..., 1::2, ::2]),
                         torch.maximum(x[..., ::2, 1::2], x[..., 1::2, 1::2]))


class UNet(nn.Module):
    """U-Net ``(N, in_channels, H, W) -> (N, n_classes, H, W)`` logits.

    Args:
        in_channels: input channels (1: the fluoroscopic image).
        n_classes: output classes (6: background + 5 feature classes).
        base_width: channels of the first level (64 in the original; the width multiplier).
        depth: number of poolings (4 in the original: five levels).
        input_stride: input pixels per pixel of the first level (1, 2 or 4; 1 in the original): above
            1, a strided stem and a sub-pixel head (docs/training.md). It enters :attr:`config` only
            when it is not 1, so the configs of plain U-Nets stay as they were.

    Attributes:
        pad_multiple: inputs are padded to a multiple of this many pixels (``2**depth * input_stride``).

    Raises:
        ValueError: a size is not an integer of its range, or ``input_stride`` is not 1, 2 or 4.
    """

    def __init__(self, in_channels: int = 1, n_classes: int = 6, base_width: int = 64, depth: int = 4,
                 input_stride: int = 1):
        super().__init__()
        for name, value, low in (("in_channels", in_channels, 1), ("n_classes", n_classes, 2),
                                 ("base_width", base_width, 1), ("depth", depth, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if isinstance(input_stride, bool) or not isinstance(input_stride, int) or input_stride not in (1, 2, 4):
            raise ValueError(f"input_stride must be 1, 2 or 4 (input pixels per first-level pixel), "
                             f"got {input_stride!r}")
        self.config = {"arch": "unet", "in_channels": in_channels, "n_classes": n_classes,
                       "base_width": base_width, "depth": depth}
        if input_stride != 1:
            self.config["input_stride"] = input_stride
        self.depth, self.input_stride = depth, input_stride
        self.pad_multiple = 2 ** depth * input_stride
        widths = [base_width * 2 ** i for i in range(depth + 1)]
        s = input_stride
        self.stem = None if s == 1 else nn.Sequential(
            nn.Conv2d(in_channels, widths[0], 2 * s, stride=s, padding=s // 2, bias=False),
            nn.BatchNorm2d(widths[0]), nn.ReLU(inplace=True))
        self.down = nn.ModuleList([_block(in_channels if s == 1 else widths[0], widths[0])] +
                                  [_block(widths[i - 1], widths[i]) for i in range(1, depth + 1)])
        self.up = nn.ModuleList([nn.ConvTranspose2d(widths[i], widths[i - 1], 2, stride=2)
                                 for i in range(depth, 0, -1)])
        self.dec = nn.ModuleList([_block(2 * widths[i - 1], widths[i - 1]) for i in range(depth, 0, -1)])
        self.head = nn.Conv2d(widths[0], n_classes, 1) if s == 1 else nn.Sequential(
            nn.Conv2d(widths[0], n_classes * s * s, 3, padding=1), nn.PixelShuffle(s))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != self.config["in_channels"]:
            raise ValueError(f"x must be (N, {self.config['in_channels']}, H, W), got {tuple(x.shape)}")
        rows, cols = x.shape[-2:]
        return self.head(self.features(self.pad(x)))[..., :rows, :cols]

    def pad(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` ``(N, C, H, W)`` padded at its bottom and right to multiples of :attr:`pad_multiple`
        (reflected, or replicated where the image is smaller than the padding), as :meth:`forward`
        pads its input; ``x`` itself where no padding is needed."""
        rows, cols = x.shape[-2:]
        m = self.pad_multiple
        pad_r, pad_c = (-rows) % m, (-cols) % m
        if not (pad_r or pad_c):
            return x
        mode = "reflect" if min(rows, cols) > max(pad_r, pad_c) else "replicate"
        return F.pad(x, (0, pad_c, 0, pad_r), mode=mode)

    def features(self, x: torch.Tensor, pool=None) -> torch.Tensor:
        """The stem (if any) and the encoder-decoder before the head, on ``x`` whose rows and columns
        are multiples of :attr:`pad_multiple`: the last decoder block's output (on the first level's
        grid). ``pool``: the 2x2 max-pooling between levels (None: ``F.max_pool2d(x, 2)``; inference
        may pass an equivalent, e.g. :func:`max_pool_2x2`)."""
        if self.stem is not None:
            x = self.stem(x)
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2) if pool is None else pool(x)
            x = block(x)
            skips.append(x)
        skips.pop()
        for up, dec in zip(self.up, self.dec):
            x = dec(torch.cat([skips.pop(), up(x)], dim=1))
        return x
