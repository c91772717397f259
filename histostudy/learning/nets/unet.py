"""U-Net for feature segmentation (paper §II-B.2; Ronneberger et al. 2015): a plain torch module.

One input channel (the standardised fluoroscopic image, see :func:`histostudy.learning.preprocess.prepare_image`)
and six output channels (background + the five :class:`~histostudy.transducer.Feature` classes),
logits per pixel at the input's resolution. Each level is two 3x3 convolutions with batch
normalisation and ReLU; the encoder halves the resolution with 2x2 max pooling, the decoder doubles
it with a 2x2 transposed convolution and concatenates the encoder's features. Level ``i`` has
``base_width * 2**i`` channels; the original U-Net is ``base_width=64, depth=4`` (64 ... 1024).

Inputs of any size are accepted: they are padded (reflect) to a multiple of ``2**depth`` and the
logits are cropped back, so a full 1240x960 frame (or its 0.5x downscale) runs in one pass.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["UNet"]


def _block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
    )


class UNet(nn.Module):
    """U-Net ``(N, in_channels, H, W) -> (N, n_classes, H, W)`` logits.

    Args:
        in_channels: input channels (1: the fluoroscopic image).
        n_classes: output classes (6: background + 5 feature classes).
        base_width: channels of the first level (64 in the original; the width multiplier).
        depth: number of poolings (4 in the original: five levels).
    """

    def __init__(self, in_channels: int = 1, n_classes: int = 6, base_width: int = 64, depth: int = 4):
        super().__init__()
        for name, value, low in (("in_channels", in_channels, 1), ("n_classes", n_classes, 2),
                                 ("base_width", base_width, 1), ("depth", depth, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        self.config = {"arch": "unet", "in_channels": in_channels, "n_classes": n_classes,
                       "base_width": base_width, "depth": depth}
        self.depth = depth
        widths = [base_width * 2 ** i for i in range(depth + 1)]
        self.down = nn.ModuleList([_block(in_channels, widths[0])] +
                                  [_block(widths[i - 1], widths[i]) for i in range(1, depth + 1)])
        self.up = nn.ModuleList([nn.ConvTranspose2d(widths[i], widths[i - 1], 2, stride=2)
                                 for i in range(depth, 0, -1)])
        self.dec = nn.ModuleList([_block(2 * widths[i - 1], widths[i - 1]) for i in range(depth, 0, -1)])
        self.head = nn.Conv2d(widths[0], n_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != self.config["in_channels"]:
            raise ValueError(f"x must be (N, {self.config['in_channels']}, H, W), got {tuple(x.shape)}")
        rows, cols = x.shape[-2:]
        m = 2 ** self.depth
        pad_r, pad_c = (-rows) % m, (-cols) % m
        if pad_r or pad_c:
            mode = "reflect" if min(rows, cols) > max(pad_r, pad_c) else "replicate"
            x = F.pad(x, (0, pad_c, 0, pad_r), mode=mode)
        return self.head(self.features(x))[..., :rows, :cols]

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The encoder-decoder before the 1x1 head, on ``x`` whose rows and columns are multiples of
        ``2**depth``: the last decoder block's output."""
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        skips.pop()
        for up, dec in zip(self.up, self.dec):
            x = dec(torch.cat([skips.pop(), up(x)], dim=1))
        return x
