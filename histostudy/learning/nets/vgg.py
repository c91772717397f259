"""VGG19 orientation network (paper §II-B.4; Simonyan & Zisserman 2015), a plain torch module: a
36-class classifier of hemisphere orientations, then an azimuth and elevation regressor
(docs/training.md, "The networks").
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ANGLE_ENCODINGS", "VGG19", "VGG19_STAGES"]

#: How the regressor outputs the azimuth: the paper's angle, or a point (cos, sin) of the plane.
ANGLE_ENCODINGS = ("angles", "cos_sin")

#: Convolutions per stage and their channels at width 1 (configuration "E": 16 convolutions).
VGG19_STAGES: tuple[tuple[int, int], ...] = ((2, 64), (2, 128), (4, 256), (4, 512), (4, 512))


class VGG19(nn.Module):
    """VGG19 ``(N, 1, H, W)`` -> class logits ``(N, n_classes)`` or angles ``(N, 2)`` rad.

    Args:
        width: channel multiplier (1.0: the original 64 ... 512 and 4096 hidden units).
        n_classes: classifier outputs (36 orientation classes).
        in_channels: input channels (1).
        head: ``"classifier"`` (logits; softmax in the loss) or ``"regressor"`` (sigmoid of the
            logits, then a linear layer to ``(azimuth, elevation)`` in rad).
        dropout: dropout probability of the two hidden fully connected layers.
        batch_norm: batch normalisation after every convolution (torchvision's ``vgg19_bn``
            variant of the same configuration). The paper does not say; without it a narrow
            19-layer stack barely starts learning in the few thousand steps a CPU affords.
        angle_encoding: the regressor's azimuth output: ``"angles"`` (the paper's two outputs) or
            ``"cos_sin"`` (docs/training.md).

    Raises:
        ValueError: an argument is out of its range (the message names it).
    """

    def __init__(self, width: float = 1.0, n_classes: int = 36, in_channels: int = 1,
                 head: str = "classifier", dropout: float = 0.5, batch_norm: bool = False,
                 angle_encoding: str = "angles"):
        super().__init__()
        if not (isinstance(width, (int, float)) and 0 < float(width) <= 4):
            raise ValueError(f"width must be a number in (0, 4], got {width!r}")
        if isinstance(n_classes, bool) or not isinstance(n_classes, int) or n_classes < 2:
            raise ValueError(f"n_classes must be an integer >= 2, got {n_classes!r}")
        if head not in ("classifier", "regressor"):
            raise ValueError(f"head must be 'classifier' or 'regressor', got {head!r}")
        if angle_encoding not in ANGLE_ENCODINGS:
            raise ValueError(f"angle_encoding must be one of {ANGLE_ENCODINGS}, got {angle_encoding!r}")
        if not isinstance(batch_norm, bool):
            raise ValueError(f"batch_norm must be True or False, got {batch_norm!r}")
        if not (0.0 <= float(dropout) < 1.0):
            raise ValueError(f"dropout must be in [0, 1), got {dropout!r}")
        self.config: dict = {"arch": "vgg19", "width": float(width), "n_classes": n_classes,
                       "in_channels": in_channels, "head": head, "dropout": float(dropout)}
        if batch_norm:
            # recorded only when set, so that manifests written before the option still match
            self.config["batch_norm"] = True
        if angle_encoding != "angles":
            # likewise: the paper's encoding is the default and goes unrecorded
            self.config["angle_encoding"] = angle_encoding
        layers: list[nn.Module] = []
        c_in = in_channels
        for n_conv, channels in VGG19_STAGES:
            c_out = max(1, int(round(channels * width)))
            for _ in range(n_conv):
                if batch_norm:
                    layers += [nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out),
                               nn.ReLU(inplace=True)]
                else:
                    layers += [nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(inplace=True)]
                c_in = c_out
            layers.append(nn.MaxPool2d(2))
        self.features = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d((7, 7))
        hidden = max(1, int(round(4096 * width)))
        self.classifier = nn.Sequential(
            nn.Linear(c_in * 49, hidden), nn.ReLU(inplace=True), nn.Dropout(dropout),
            nn.Linear(hidden, hidden), nn.ReLU(inplace=True), nn.Dropout(dropout),
            nn.Linear(hidden, n_classes),
        )
        self.regressor = nn.Linear(n_classes, self._regressor_outputs) if head == "regressor" else None
        # The initialisation of torchvision's VGG (He-normal convolutions, N(0, 0.01) linear
        # layers, zero biases): without batch norm, PyTorch's default initialisation leaves the
        # 19-layer stack's gradients too small for plain SGD at lr 0.001 to start.
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0.0, 0.01)
                nn.init.zeros_(m.bias)

    @property
    def _regressor_outputs(self) -> int:
        return 3 if self.config.get("angle_encoding") == "cos_sin" else 2

    @property
    def n_convolutions(self) -> int:
        return sum(isinstance(m, nn.Conv2d) for m in self.features)

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """The classifier's logits ``(N, n_classes)`` whatever the head."""
        if x.ndim != 4 or x.shape[1] != self.config["in_channels"]:
            raise ValueError(f"x must be (N, {self.config['in_channels']}, H, W), got {tuple(x.shape)}")
        return self.classifier(torch.flatten(self.pool(self.features(x)), 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = self.logits(x)
        if self.regressor is None:
            return z
        y = self.regressor(torch.sigmoid(z))
        if self._regressor_outputs == 3:
            return torch.stack([torch.atan2(y[:, 1], y[:, 0]), y[:, 2]], dim=1)
        return y

    def to_regressor(self, class_angles_rad=None) -> VGG19:
        """Turn the classifier into the regressor in place (§II-B.4) and return it.

        The new linear layer maps the ``n_classes`` sigmoid outputs to ``(azimuth, elevation)`` rad.
        It starts with zero weights and the bias ``(0, 1)``: azimuth 0 and elevation 1 rad, the
        mean elevation of directions uniform on the hemisphere, so the first regression steps do
        not push large random errors back into the trained features.

        With ``angle_encoding="cos_sin"`` and ``class_angles_rad`` (``(n_classes, 2)`` azimuth and
        elevation of the classes, :func:`histostudy.learning.orientation.hemisphere_angles`), the ``(c, s)``
        rows start as each class's ``(cos, sin)`` of its azimuth: the first azimuth is the sigmoid-
        weighted vote of the classes, what the classifier already knows. Without them they start
        at zero with the bias ``(1, 0)`` (azimuth 0; ``atan2`` has no gradient at ``(0, 0)``).
        """
        if self.regressor is not None:
            raise ValueError("the network already has the regressor head")
        n = int(self.config["n_classes"])
        outputs = self._regressor_outputs
        self.regressor = nn.Linear(n, outputs)
        with torch.no_grad():
            self.regressor.weight.zero_()
            if outputs == 2:
                self.regressor.bias.copy_(torch.tensor([0.0, 1.0]))
            elif class_angles_rad is None:
                self.regressor.bias.copy_(torch.tensor([1.0, 0.0, 1.0]))
            else:
                angles = torch.as_tensor(class_angles_rad, dtype=torch.float32)
                if tuple(angles.shape) != (n, 2) or not torch.isfinite(angles).all():
                    raise ValueError(f"class_angles_rad must be finite ({n}, 2) azimuth and elevation in rad, "
                                     f"got shape {tuple(angles.shape)}")
                self.regressor.weight[0] = torch.cos(angles[:, 0])
                self.regressor.weight[1] = torch.sin(angles[:, 0])
                self.regressor.bias.copy_(torch.tensor([0.0, 0.0, 1.0]))
        self.config = {**self.config, "head": "regressor"}
        return self
