"""Feature segmentation of fluoroscopic frames (paper §II-B.2): the :class:`Segmenter` interface, the
oracle that errs as the paper's Table I (:class:`OracleSegmenter`) and the shipped U-Nets
(:func:`default_segmenter`, run by :class:`~histostudy.learning.inference.runner.UNetRunner`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import cv2
import numpy as np

from histostudy.core import stage
from histostudy.imaging import Frame
from histostudy.transducer import FEATURE_CLASSES, Feature

if TYPE_CHECKING:
    from .inference import UNetRunner

__all__ = ["ORACLE_DEGRADATIONS", "OracleSegmenter", "SegmentationDegradation", "Segmenter", "default_segmenter",
           "degrade_labels", "keep_largest_component", "masks_from_labels", "tracking_segmenter"]


@runtime_checkable
class Segmenter(Protocol):
    """Turns a frame into a ``uint8`` label image of :class:`Feature` values.

    A segmenter whose labels depend on the frame alone, drawing nothing from ``rng``, says so with
    ``uses_rng = False`` (:class:`~histostudy.learning.inference.UNetRunner`); a caller may then
    segment a frame once for several estimates (:func:`~histostudy.study.pose.experiments.run_pose_study`).
    Without the attribute a segmenter is taken to draw, and is called every time.
    """

    def segment(self, frame: Frame, rng: np.random.Generator) -> np.ndarray: ...


def masks_from_labels(labels: np.ndarray) -> dict[Feature, np.ndarray]:
    """Boolean mask per feature class (background excluded) of a label image.

    Args:
        labels: ``(rows, cols)`` :class:`~histostudy.transducer.Feature` values.

    Returns:
        ``{feature: bool (rows, cols)}`` for the five feature classes.

    Raises:
        ValueError: ``labels`` is not 2-D.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f"labels must be a 2-D label image, got shape {labels.shape}")
    return {k: labels == k for k in FEATURE_CLASSES}


def keep_largest_component(labels: np.ndarray) -> np.ndarray:
    """The labels of the largest 8-connected component of the segmented foreground only.

    The transducer projects as one connected body (elements, rim and screws touch), so in a frame
    of one transducer any other component is a false positive (docs/learned-stages.md).

    Args:
        labels: ``(rows, cols)`` :class:`~histostudy.transducer.Feature` values.

    Returns:
        A copy, same shape and dtype, with every pixel outside that component set to background.

    Raises:
        ValueError: ``labels`` is not 2-D.
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

    Raises:
        ValueError: a key is not a feature class, a fraction is outside (0, 1], or
            ``blob_sigma_px`` is negative or not finite.
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
    """The frame's reference labels, degraded the way a network errs (paper Table I), or perfect.

    Args:
        degradation: how the labels err (:class:`SegmentationDegradation`); None: the reference
            labels as they are.

    Raises:
        ValueError: :meth:`named` of an unknown name; :meth:`segment` of a frame without reference labels.
        TypeError: :meth:`segment` with a degradation and no ``numpy.random.Generator``.
    """

    degradation: SegmentationDegradation | None = None

    @classmethod
    def named(cls, degradation: str) -> OracleSegmenter:
        """The oracle of a study config: ``"table1"`` errs as the paper's U-Net (Table I), ``"none"`` not at all."""
        if degradation not in ORACLE_DEGRADATIONS:
            raise ValueError(f"degradation must be one of {ORACLE_DEGRADATIONS}, got {degradation!r}")
        return cls(SegmentationDegradation.paper_table1() if degradation == "table1" else None)

    @stage("segment")
    def segment(self, frame: Frame, rng: np.random.Generator | None = None) -> np.ndarray:
        if frame.labels is None:
            from .checkpoints import MODELS_DIR

            raise ValueError(f"OracleSegmenter needs a frame with reference labels; the frame of view "
                             f"{frame.view.name!r} has none (real frames need a learned segmenter: the shipped "
                             f"U-Net, unet_standard.safetensors, is looked for in {MODELS_DIR})")
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
            lower_classes = (Feature.BACKGROUND, *FEATURE_CLASSES[: FEATURE_CLASSES.index(k)])
            lower = np.isin(reference, [int(c) for c in lower_classes])
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


# --- the shipped U-Nets (§II-B.2) -------------------------------------------------------------


def default_segmenter() -> UNetRunner | None:
    """The shipped U-Net (``data/models/unet_standard``), run as trained (precision ``"reference"``).

    Returns:
        Its :class:`~histostudy.learning.inference.runner.UNetRunner`, or None (with a warning) when
        the weights are missing or fail their hash or configuration check (callers then fall back to
        :class:`OracleSegmenter` and say so).
    """
    from .checkpoints import load_shipped
    from .inference import UNetRunner

    return load_shipped("unet_standard", UNetRunner.load, "U-Net")


def tracking_segmenter() -> UNetRunner | None:
    """The shipped U-Net trained for tracking (``data/models/unet_tracking``: input scale 0.25,
    ``histostudy train segmentation_tracking``; docs/tracking.md, "A network trained for tracking").

    Returns:
        Its :class:`~histostudy.learning.inference.runner.UNetRunner` (precision ``"reference"``), or
        None (with a warning) when the weights are missing or fail their hash or configuration check.
    """
    from .checkpoints import load_shipped
    from .inference import UNetRunner

    return load_shipped("unet_tracking", UNetRunner.load, "tracking U-Net")
