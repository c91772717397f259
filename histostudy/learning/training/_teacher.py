"""Training a segmentation network on a teacher U-Net's labels (distillation, for the tracking networks;
docs/training.md, "The training package").
"""

from __future__ import annotations

import numpy as np
import torch

from ..checkpoints import load_network

__all__ = ["load_teacher", "teacher_labeller"]


def load_teacher(path, scale: float, device) -> tuple[torch.nn.Module, dict]:
    """``(network, record)``: the U-Net of checkpoint ``path`` in eval mode on ``device``, and what
    the exported manifest records of it (path, SHA-256, input scale). ValueError when it is no
    U-Net or was trained at another input scale than ``scale``."""
    net, manifest = load_network(path)
    config = manifest["config"]
    if config.get("arch") != "unet":
        raise ValueError(f"teacher {str(path)!r} is a {config.get('arch')!r} network; expected a U-Net checkpoint")
    teacher_scale = manifest.get("input_scale")
    if teacher_scale is None or abs(float(teacher_scale) - float(scale)) > 1e-12:
        raise ValueError(f"teacher {str(path)!r} reads input scale {teacher_scale!r}, but the run trains at "
                         f"scale {scale!r}; expected a teacher of the run's scale")
    net.to(device)
    for p in net.parameters():
        p.requires_grad_(False)
    return net, {"path": str(path), "sha256": manifest["sha256"], "input_scale": float(teacher_scale)}


def teacher_labeller(teacher: torch.nn.Module, device):
    """The ``target_labels`` of :class:`~.datasets.HybridImageDataset` for ``teacher``: a network input
    ``(h, w)`` (standardised, at the run's scale) -> the teacher's arg-max labels, ``int64`` on the
    same grid."""

    @torch.no_grad()
    def labels(image: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32))[None, None].to(device)
        return teacher(x).argmax(dim=1)[0].cpu().numpy().astype(np.int64)

    return labels
