"""The networks' input transforms (paper §II-B.2), the same in training and at inference:
:func:`prepare_image` (area downscaling, then per-image standardisation) and :func:`pool_labels`
(each block the class of highest overlap priority).
"""

from __future__ import annotations

import cv2
import numpy as np

from histostudy.core import check_unit_fraction
from histostudy.transducer import LABEL_PRIORITY, Feature

__all__ = ["pool_labels", "prepare_image"]


def prepare_image(image, scale: float) -> np.ndarray:
    """The network input of a frame's line-integral image: float32 ``(rows*scale, cols*scale)``.

    Area-averaged downscaling by ``scale`` (1, 1/2, 1/4, ...; 0.25 turns 1240x960 into the
    paper's 310x240, §II-B.4), then per-image standardisation (zero mean, unit SD), which makes the
    input independent of dose and patient thickness offsets.
    """
    img = np.asarray(image)
    if img.ndim != 2 or not np.issubdtype(img.dtype, np.number):
        raise ValueError(f"image must be a 2-D numeric array, got shape {img.shape} dtype {img.dtype}")
    k = check_unit_fraction(scale)
    img = img.astype(np.float32)
    if k > 1:
        rows, cols = img.shape
        if rows % k or cols % k:
            raise ValueError(f"image shape {img.shape} is not divisible by 1/scale = {k}")
        img = cv2.resize(img, (cols // k, rows // k), interpolation=cv2.INTER_AREA)
    sd = float(img.std())
    return ((img - float(img.mean())) / (sd if sd > 0 else 1.0)).astype(np.float32)


_RANK = np.zeros(256, np.uint8)
for _rank, _feature in enumerate(reversed(LABEL_PRIORITY), start=1):
    _RANK[int(_feature)] = _rank
_LABEL_OF_RANK = np.zeros(len(LABEL_PRIORITY) + 1, np.uint8)
_LABEL_OF_RANK[_RANK[[int(f) for f in Feature]]] = [int(f) for f in Feature]


def pool_labels(labels, scale: float) -> np.ndarray:
    """A label image downscaled by an integer factor: each block takes its highest-priority class
    present (the overlap rule of §II-B.2).

    Args:
        labels: ``(rows, cols)`` :class:`~histostudy.transducer.Feature` values.
        scale: 1, 1/2, 1/4, ... (label pixels per input pixel).

    Returns:
        ``uint8 (rows * scale, cols * scale)`` labels (a ``uint8`` copy at scale 1).

    Raises:
        ValueError: ``labels`` is not 2-D, ``scale`` is not ``1 / integer``, or the shape is not
            divisible by ``1 / scale``.
    """
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ValueError(f"labels must be a 2-D label image, got shape {lab.shape}")
    k = check_unit_fraction(scale)
    if k == 1:
        return lab.astype(np.uint8)
    rows, cols = lab.shape
    if rows % k or cols % k:
        raise ValueError(f"labels shape {lab.shape} is not divisible by 1/scale = {k}")
    ranks = _RANK[lab.astype(np.uint8)].reshape(rows // k, k, cols // k, k).max(axis=(1, 3))
    return _LABEL_OF_RANK[ranks]
