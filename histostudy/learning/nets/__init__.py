"""The networks of the learned stages as plain torch modules: :class:`UNet` (§II-B.2), :class:`VGG19`
(§II-B.4), and :func:`build_network`, which rebuilds either from its configuration dict without pickle
(docs/training.md, "The networks").
"""

from __future__ import annotations

from .unet import UNet
from .vgg import VGG19

__all__ = ["UNet", "VGG19", "build_network"]


def build_network(config: dict):
    """A fresh network from its configuration, so that a checkpoint is rebuilt without pickle.

    Args:
        config: ``{"arch": "unet" | "vgg19", ...}``, the rest the network's constructor arguments
            (the dict each network records in ``.config`` and a checkpoint manifest stores).

    Returns:
        A new :class:`UNet` or :class:`VGG19` (random weights, training mode).

    Raises:
        ValueError: ``config`` is not a dict with an ``"arch"`` key, names another architecture, or
            holds arguments that architecture does not take or rejects.
    """
    if not isinstance(config, dict) or "arch" not in config:
        raise ValueError(f"config must be a dict with an 'arch' key, got {config!r}")
    kwargs = {k: v for k, v in config.items() if k != "arch"}
    try:
        if config["arch"] == "unet":
            return UNet(**kwargs)
        if config["arch"] == "vgg19":
            return VGG19(**kwargs)
    except TypeError as exc:
        raise ValueError(f"config {config!r} does not fit arch {config['arch']!r}: {exc}") from None
    raise ValueError(f"config['arch'] must be 'unet' or 'vgg19', got {config['arch']!r}")
