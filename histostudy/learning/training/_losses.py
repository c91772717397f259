"""The losses of the learned stages and their validation metrics (paper §II-B.2, §II-B.4):
cross-entropy with an optional soft Dice term, and the angle loss in rad² (docs/training.md,
"The training package").
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.nn import functional as F

from histostudy.transducer import FEATURE_CLASSES, Feature

__all__ = ["angle_loss", "dice_loss"]


def angle_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean of ``sin(el)^2 wrap(az_p - az)^2 + (el_p - el)^2`` (rad²) over a batch of ``(az, el)`` rows."""
    d_az = pred[:, 0] - target[:, 0]
    d_az = torch.atan2(torch.sin(d_az), torch.cos(d_az))
    return (torch.sin(target[:, 1]) ** 2 * d_az ** 2 + (pred[:, 1] - target[:, 1]) ** 2).mean()


#: The feature classes' label values (the Dice loss's default classes).
_FEATURE_LABELS = tuple(int(k) for k in FEATURE_CLASSES)


def dice_loss(logits: torch.Tensor, labels: torch.Tensor, classes=_FEATURE_LABELS, eps: float = 1.0) -> torch.Tensor:
    """``1 - mean_k Dice_k`` of the softmax of ``logits`` (B, C, H, W) against integer ``labels``
    (B, H, W), over ``classes``, each class's pixels pooled over the batch; ``eps`` keeps a class
    absent from the batch finite (its Dice then rewards predicting none of it)."""
    prob = torch.softmax(logits, dim=1)
    dices = []
    for k in classes:
        p, t = prob[:, k], (labels == k).to(prob.dtype)
        dices.append((2 * (p * t).sum() + eps) / (p.sum() + t.sum() + eps))
    return 1 - torch.stack(dices).mean()


def stage_loss(stage: str, net, batch, device, class_weights=None, kind: str = "cross_entropy"
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(loss, network output)`` of ``net`` on ``batch`` with the loss of ``stage`` (``segment``:
    cross-entropy, weighted by ``class_weights``, plus :func:`dice_loss` when ``kind`` says so;
    ``classify``: cross-entropy; ``regress``: :func:`angle_loss`)."""
    x = batch["image"].to(device)
    if stage == "segment":
        y = batch["labels"].to(device)
        out = net(x)
        w = None if class_weights is None else torch.tensor(class_weights, dtype=out.dtype, device=device)
        loss = F.cross_entropy(out, y, weight=w)
        if kind == "cross_entropy+dice":
            loss = loss + dice_loss(out, y)
        return loss, out
    if stage == "classify":
        out = net(x)
        return F.cross_entropy(out, batch["class"].to(device)), out
    out = net(x)
    return angle_loss(out, batch["angles"].to(device)), out


@torch.no_grad()
def validation_metrics(stage: str, net, loader, device, class_weights=None, kind: str = "cross_entropy") -> dict:
    """The mean loss of :func:`stage_loss` over ``loader`` and the stage's metrics: ``segment``:
    pixel accuracy and per-class IoU; ``classify``: class accuracy; ``regress``: mean absolute
    azimuth and elevation errors in degrees. ``net`` is put back in train mode."""
    net.eval()
    total, n = 0.0, 0
    correct, pixels = 0, 0
    intersection, union = np.zeros(len(Feature)), np.zeros(len(Feature))
    az_err, el_err = [], []
    for batch in loader:
        loss, out = stage_loss(stage, net, batch, device, class_weights, kind)
        b = batch["image"].shape[0]
        total += loss.item() * b
        n += b
        if stage == "segment":
            pred, ref = out.argmax(1).cpu(), batch["labels"]
            correct += int((pred == ref).sum())
            pixels += ref.numel()
            for k in range(len(Feature)):
                p, r = pred == k, ref == k
                intersection[k] += int((p & r).sum())
                union[k] += int((p | r).sum())
        elif stage == "classify":
            correct += int((out.argmax(1).cpu() == batch["class"]).sum())
            pixels += b
        else:
            p, t = out.double().cpu(), batch["angles"].double()
            d = p[:, 0] - t[:, 0]
            az_err.append(torch.atan2(torch.sin(d), torch.cos(d)).abs())
            el_err.append((p[:, 1] - t[:, 1]).abs())
    net.train()
    metrics = {"loss": total / max(n, 1)}
    if stage == "segment":
        metrics["pixel_accuracy"] = correct / max(pixels, 1)
        # per-class IoU of the validation pixels (NaN for a class absent from prediction and reference)
        for k in Feature:
            metrics[f"iou_{k.name.lower()}"] = float(intersection[k] / union[k]) if union[k] else float("nan")
    elif stage == "classify":
        metrics["class_accuracy"] = correct / max(pixels, 1)
    else:
        metrics["azimuth_mae_deg"] = math.degrees(torch.cat(az_err).mean().item())
        metrics["elevation_mae_deg"] = math.degrees(torch.cat(el_err).mean().item())
    return metrics
