"""Feature segmentation of fluoroscopic frames (paper §II-B.2): the interface and the oracle.

A :class:`Segmenter` turns a :class:`~histostudy.imaging.frame.Frame` into a label image: ``uint8
(rows, cols)`` of :class:`~histostudy.transducer.Feature` values, one class per pixel, overlaps
resolved by the paper's priority (what the U-Net's arg-max gives). The learned U-Net implements
the same interface (:class:`UNetSegmenter`, with the shipped weights from :func:`default_segmenter`).

:class:`OracleSegmenter` returns the frame's reference labels, optionally degraded the way a
network errs (:class:`SegmentationDegradation`): each class keeps only a fraction of its pixels
(recall) in spatially correlated blobs — thin features lose pixels to the element underneath —
and gains false positives next to its true pixels (precision), so that a pose study can run with
segmentation errors of the size of the paper's Table I.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from histostudy.imaging import Frame
from histostudy.transducer import FEATURE_CLASSES, Feature

__all__ = ["keep_largest_component", "OracleSegmenter", "SegmentationDegradation", "Segmenter", "UNetSegmenter", "default_segmenter",
           "masks_from_labels", "tracking_segmenter"]


@runtime_checkable
class Segmenter(Protocol):
    """Turns a frame into a ``uint8`` label image of :class:`Feature` values."""

    def segment(self, frame: Frame, rng: np.random.Generator) -> np.ndarray: ...


def masks_from_labels(labels: np.ndarray) -> dict[Feature, np.ndarray]:
    """Boolean mask per feature class (background excluded) of a label image."""
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be a 2-D label image, got shape {labels.shape}")
    return {k: labels == k for k in FEATURE_CLASSES}


def keep_largest_component(labels: np.ndarray) -> np.ndarray:
    """``labels`` with every pixel outside the largest 8-connected component of the segmented
    foreground (any class > 0) set to background; a copy, same shape and dtype.

    The transducer projects as one connected body (elements, rim and screws touch), so in a frame
    of one transducer any other component is a false positive: a learned segmentation marks
    patches of bone or phantom edges as transducer (measured on random abdomen scenes: up to a
    third of a view's segmented pixels, 99 % of the true transducer pixels in the component kept).
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be a 2-D label image, got shape {labels.shape}")
    n, components, stats, _ = cv2.connectedComponentsWithStats((labels > 0).astype(np.uint8), connectivity=8)
    if n <= 2:
        return labels.copy()
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return np.where(components == largest, labels, 0).astype(labels.dtype)


def _table1_fraction(column: int) -> dict[Feature, float]:
    # Table I of the paper, per class: precision, recall (percent).
    table = {
        Feature.TRANSDUCER: (96.2, 89.2),
        Feature.OUTER_BOUNDARY: (93.0, 48.6),
        Feature.INNER_BOUNDARY: (97.6, 41.2),
        Feature.GAPS: (90.4, 59.9),
        Feature.SCREWS: (82.2, 68.4),
    }
    return {k: v[column] / 100.0 for k, v in table.items()}


@dataclass(frozen=True)
class SegmentationDegradation:
    """How an oracle segmentation errs, per feature class.

    Attributes:
        recall: fraction of each class's reference pixels that stay in the class (1 = none lost).
        precision: fraction of the class's predicted pixels that are truly of the class
            (1 = no false positives); false positives are placed next to true pixels.
        blob_sigma_px: spatial correlation length (Gaussian sigma, px) of lost and added pixels,
            so that errors come in blobs as a network's do, not as salt-and-pepper.
    """

    recall: dict = field(default_factory=lambda: {k: 1.0 for k in FEATURE_CLASSES})
    precision: dict = field(default_factory=lambda: {k: 1.0 for k in FEATURE_CLASSES})
    blob_sigma_px: float = 2.0

    def __post_init__(self):
        for name in ("recall", "precision"):
            table = getattr(self, name)
            for k, v in table.items():
                if Feature(k) not in FEATURE_CLASSES:
                    raise ValueError(f"{name} has key {k!r}; expected one of {[f.name for f in FEATURE_CLASSES]}")
                if not (0.0 < float(v) <= 1.0):
                    raise ValueError(f"{name}[{Feature(k).name}] must be in (0, 1], got {v!r}")
        if not (np.isfinite(self.blob_sigma_px) and self.blob_sigma_px >= 0):
            raise ValueError(f"blob_sigma_px must be finite and >= 0, got {self.blob_sigma_px!r}")

    @classmethod
    def paper_table1(cls, blob_sigma_px: float = 2.0) -> SegmentationDegradation:
        """Per-class recall and precision of the paper's Table I."""
        return cls(recall=_table1_fraction(1), precision=_table1_fraction(0), blob_sigma_px=blob_sigma_px)


# Where a lost pixel goes: thin features lie on the elements, the elements on the background.
_FALLBACK = {
    Feature.TRANSDUCER: Feature.BACKGROUND,
    Feature.OUTER_BOUNDARY: Feature.TRANSDUCER,
    Feature.INNER_BOUNDARY: Feature.TRANSDUCER,
    Feature.GAPS: Feature.TRANSDUCER,
    Feature.SCREWS: Feature.TRANSDUCER,
}


#: Names of the oracle degradations a study config may ask for (:meth:`OracleSegmenter.named`).
ORACLE_DEGRADATIONS = ("table1", "none")


@dataclass(frozen=True)
class OracleSegmenter:
    """The frame's reference labels, degraded by ``degradation`` (None: perfect segmentation)."""

    degradation: SegmentationDegradation | None = None

    @classmethod
    def named(cls, degradation: str) -> OracleSegmenter:
        """The oracle of a study config: ``"table1"`` errs as the paper's U-Net (Table I), ``"none"`` not at all."""
        if degradation not in ORACLE_DEGRADATIONS:
            raise ValueError(f"degradation must be one of {ORACLE_DEGRADATIONS}, got {degradation!r}")
        return cls(SegmentationDegradation.paper_table1() if degradation == "table1" else None)

    def segment(self, frame: Frame, rng: np.random.Generator | None = None) -> np.ndarray:
        if frame.labels is None:
            raise ValueError(f"OracleSegmenter needs a frame with reference labels; the frame of view "
                             f"{frame.view.name!r} has none (real frames need a learned segmenter)")
        labels = frame.labels.copy()
        if self.degradation is None:
            return labels
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator for a degraded oracle, got {type(rng).__name__}")
        return degrade_labels(labels, self.degradation, rng)


def _blob_field(shape, sigma_px: float, rng: np.random.Generator) -> np.ndarray:
    noise = rng.standard_normal(shape).astype(np.float32)
    if sigma_px > 0:
        noise = cv2.GaussianBlur(noise, (0, 0), sigmaX=sigma_px, borderType=cv2.BORDER_REFLECT)
    return noise


def degrade_labels(labels: np.ndarray, degradation: SegmentationDegradation, rng: np.random.Generator) -> np.ndarray:
    """Apply recall loss and false positives per class (see :class:`SegmentationDegradation`).

    Classes are processed from the lowest to the highest overlap priority so that a thin feature's
    false positives may cover element pixels but never another thin feature's true pixels.
    """
    out = np.asarray(labels, dtype=np.uint8).copy()
    reference = out.copy()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    for k in FEATURE_CLASSES:
        ref = reference == k
        n_ref = int(ref.sum())
        if n_ref == 0:
            continue
        recall = float(degradation.recall.get(k, 1.0))
        precision = float(degradation.precision.get(k, 1.0))
        keep = ref
        if recall < 1.0:
            score = _blob_field(out.shape, degradation.blob_sigma_px, rng)
            n_drop = int(round(n_ref * (1.0 - recall)))
            if n_drop:
                threshold = np.partition(score[ref], n_drop - 1)[n_drop - 1]
                drop = ref & (score <= threshold)
                out[drop] = _FALLBACK[k]
                keep = ref & ~drop
        if precision < 1.0:
            n_fp = int(round(keep.sum() * (1.0 / precision - 1.0)))
            # candidates: pixels next to the class that hold a lower-priority class or background
            lower = np.isin(reference, [int(c) for c in (Feature.BACKGROUND, *FEATURE_CLASSES[: FEATURE_CLASSES.index(k)])])
            ring = np.zeros_like(ref)
            grown = keep.astype(np.uint8)
            for _ in range(8):  # widen until there is room for every false positive
                grown = cv2.dilate(grown, kernel)
                ring = grown.astype(bool) & ~ref & lower
                if ring.sum() >= n_fp:
                    break
            n_fp = min(n_fp, int(ring.sum()))
            if n_fp:
                score = _blob_field(out.shape, degradation.blob_sigma_px, rng)
                threshold = np.partition(-score[ring], n_fp - 1)[n_fp - 1]
                out[ring & (-score <= threshold)] = k
    return out


# --- the learned segmenter (§II-B.2) ----------------------------------------------------------


@dataclass(frozen=True, eq=False)
class UNetSegmenter:
    """The U-Net of §II-B.2 as a :class:`Segmenter`.

    Inference on a whole frame in one pass at the network's input scale: the line-integral image
    is area-downscaled by ``scale`` and standardised (:func:`histostudy.learning.preprocess.prepare_image`,
    the transform of training), the U-Net's logits are upsampled bilinearly (pixel centres
    aligned as in :meth:`~histostudy.imaging.carm.View.scaled`) to the frame's full resolution and the
    arg-max class of each pixel is returned, so labels always have the frame's shape. ``rng`` is
    accepted for the protocol and unused (inference is deterministic).

    With ``test_time_flips`` the logits are the mean of the network's on the image and on its three
    mirror images (left-right, up-down, both), each flipped back: the labels then mirror exactly as
    the frame does. It costs four passes for a few points of IoU on the thin classes
    (docs/learned-stages.md, "The learned stages at a new seed"), so it is offered, not the default.

    Build it with :meth:`load` from a checkpoint (:mod:`histostudy.learning.checkpoints`), or get the
    shipped one from :func:`default_segmenter`.
    """

    network: object = field(repr=False)
    scale: float = 0.5
    manifest: dict | None = field(default=None, repr=False)
    test_time_flips: bool = False

    def __post_init__(self):
        if not isinstance(self.test_time_flips, bool):
            raise TypeError(f"test_time_flips must be True or False, got {self.test_time_flips!r}")

    @classmethod
    def load(cls, path, *, test_time_flips: bool = False) -> UNetSegmenter:
        """From a U-Net checkpoint (hash and configuration checked)."""
        from .checkpoints import load_network

        net, manifest = load_network(path)
        if net.config.get("arch") != "unet" or net.config.get("n_classes") != len(Feature):
            raise ValueError(f"checkpoint {str(path)!r} holds {net.config}, expected a U-Net with {len(Feature)} classes")
        return cls(network=net, scale=float(manifest.get("input_scale", 0.5)), manifest=manifest,
                   test_time_flips=test_time_flips)

    def segment(self, frame: Frame, rng: np.random.Generator | None = None) -> np.ndarray:
        import torch
        from torch.nn import functional as F

        from .preprocess import prepare_image

        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        try:
            x = prepare_image(frame.image, self.scale)
        except ValueError as exc:
            raise ValueError(f"frame of view {frame.view.name!r} with shape {frame.image.shape} cannot be "
                             f"segmented at scale {self.scale}: {exc}") from None
        self.network.eval()
        with torch.no_grad():
            x = torch.from_numpy(x)[None, None]
            logits = self.network(x)
            if self.test_time_flips:
                for dims in ((-1,), (-2,), (-2, -1)):
                    logits = logits + torch.flip(self.network(torch.flip(x, dims)), dims)
                logits = logits / 4.0
            if logits.shape[-2:] != frame.image.shape:
                logits = F.interpolate(logits, size=frame.image.shape, mode="bilinear", align_corners=False)
            return logits[0].argmax(dim=0).to(torch.uint8).numpy()


def default_segmenter() -> UNetSegmenter | None:
    """The shipped U-Net (``data/models/unet_standard``) as a :class:`UNetSegmenter`, or None when
    the weights are missing or fail their hash or configuration check (callers then fall back to
    :class:`OracleSegmenter` and say so)."""
    from .checkpoints import load_shipped

    return load_shipped("unet_standard", UNetSegmenter.load, "U-Net")


def tracking_segmenter() -> UNetSegmenter | None:
    """The shipped U-Net trained for tracking (``data/models/unet_tracking``: input scale 0.25,
    ``histostudy train segmentation_tracking``; docs/tracking.md, "A network trained for tracking")
    as a :class:`UNetSegmenter`, or None when the weights are missing or fail their hash or
    configuration check (with a warning then)."""
    from .checkpoints import load_shipped

    return load_shipped("unet_tracking", UNetSegmenter.load, "tracking U-Net")
