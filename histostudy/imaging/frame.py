"""Fluoroscopic frames: an image of line integrals with its view, and what is known about it.

The same :class:`Frame` carries a synthetic frame (with reference labels and the true pose) and a
real one loaded from disk (labels and pose unknown: ``None``). Everything downstream —
segmentation, pose estimation, the studies — takes Frames, so real data and the synthetic study
share one code path.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from histostudy.geometry import check_rigid
from histostudy.transducer import check_label_image
from .carm import View

__all__ = ["Frame", "load_frame"]


@dataclass(frozen=True, eq=False)
class Frame:
    """A fluoroscopic image and its projection geometry.

    Attributes:
        image: ``(rows, cols)`` float32 line integrals of linear attenuation (dimensionless,
            ``-log(I / I0)``), the form the paper's C-arm preprocessing produced (§II-B.2).
        view: the :class:`~histostudy.imaging.carm.View` the image was acquired with.
        labels: ``(rows, cols)`` uint8 reference labels (values of
            :class:`~histostudy.transducer.Feature`), or None for a real frame.
        T_carm_transducer: the true 4x4 transducer pose for a synthetic frame, None for a real one.
        meta: free-form provenance (seed, noise level, source file, ...).
    """

    image: np.ndarray
    view: View
    labels: np.ndarray | None = None
    T_carm_transducer: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.view, View):
            raise TypeError(f"view must be a histostudy.imaging.carm.View, got {type(self.view).__name__}")
        image = np.asarray(self.image)
        if image.ndim != 2 or not np.issubdtype(image.dtype, np.number):
            raise ValueError(f"image must be a 2-D numeric array, got shape {image.shape} dtype {image.dtype}")
        if image.shape != self.view.shape:
            raise ValueError(f"image shape {image.shape} does not match view {self.view.name!r} shape {self.view.shape}")
        image = image.astype(np.float32, copy=False)
        if not np.all(np.isfinite(image)):
            raise ValueError("image must be finite (line integrals); found NaN or inf")
        object.__setattr__(self, "image", image)
        if self.labels is not None:
            object.__setattr__(self, "labels", check_label_image(self.labels, image.shape))
        if self.T_carm_transducer is not None:
            object.__setattr__(self, "T_carm_transducer", check_rigid(self.T_carm_transducer, "T_carm_transducer"))

    @property
    def shape(self) -> tuple[int, int]:
        return self.view.shape


def load_frame(path: str | os.PathLike, view: View, *, line_integrals: bool = True,
               air_value: float | None = None, frame_index: int | None = None, resample: bool = False) -> Frame:
    """Load a real fluoroscopic frame from ``.npy``, ``.png``/``.tif`` or DICOM (``.dcm``).

    Args:
        path: the image file.
        view: its calibrated geometry (e.g. from :func:`~histostudy.imaging.carm.load_views` or
            :meth:`~histostudy.imaging.View.from_dicom`).
        line_integrals: True when the file already holds line integrals (as the paper's
            preprocessed projections). False for raw intensities, which are converted with
            ``-log(I / air_value)``.
        air_value: unattenuated intensity ``I0`` for the conversion; default the image maximum.
        frame_index: the frame of a multi-frame file (an XA cine, a ``(frames, rows, cols)``
            ``.npy`` stack); required for those, refused for single frames.
        resample: resize an image whose size differs from ``view.shape`` onto it (area averaging
            when shrinking, bilinear when enlarging); without it such an image is refused.

    DICOM: the stored values are inverted first for ``MONOCHROME1`` (low values white), so that a
    larger value is always more X-ray intensity; then ``RescaleSlope`` / ``RescaleIntercept``
    (finite, or refused naming the tag) give the modality values.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if frame_index is not None and (isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer))
                                    or frame_index < 0):
        raise ValueError(f"frame_index must be an integer >= 0 or None, got {frame_index!r}")
    if suffix == ".npy":
        image = np.load(path, allow_pickle=False)
    elif suffix in (".png", ".tif", ".tiff"):
        import cv2

        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"path {str(path)!r} could not be read as an image")
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif suffix in (".dcm", ".dicom", ""):
        image = _dicom_pixels(path)
    else:
        raise ValueError(f"path {str(path)!r}: unknown image format {suffix!r} (expected .npy, .png, .tif, .dcm)")
    image = _one_frame(np.asarray(image, dtype=np.float64), frame_index, path)
    if image.shape != view.shape:
        if not resample:
            raise ValueError(f"path {str(path)!r} holds a {image.shape} image, the view {view.name!r} expects "
                             f"{view.shape}: pass resample=True to resize it onto the view")
        import cv2

        shrink = image.shape[0] > view.shape[0] or image.shape[1] > view.shape[1]
        image = cv2.resize(image, (view.shape[1], view.shape[0]),
                           interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if not line_integrals:
        i0 = float(image.max()) if air_value is None else float(air_value)
        if not np.isfinite(i0) or i0 <= 0:
            raise ValueError(f"air_value must be a positive intensity, got {air_value!r}")
        image = -np.log(np.clip(image, 1e-6 * i0, None) / i0)
    meta = {"source": str(path)} | ({} if frame_index is None else {"frame_index": int(frame_index)})
    return Frame(image=image.astype(np.float32), view=view, meta=meta)


def _dicom_pixels(path: Path) -> np.ndarray:
    """A DICOM object's pixel values as modality values: MONOCHROME1 inverted, rescale applied."""
    import pydicom

    ds = pydicom.dcmread(path)
    pixels = ds.pixel_array.astype(np.float64)
    if str(getattr(ds, "PhotometricInterpretation", "MONOCHROME2")).strip() == "MONOCHROME1":
        bits = int(getattr(ds, "BitsStored", getattr(ds, "BitsAllocated", 16)))
        pixels = (2.0 ** bits - 1.0) - pixels
    rescale = []
    for keyword, tag, default in (("RescaleSlope", "(0028,1053)", 1.0), ("RescaleIntercept", "(0028,1052)", 0.0)):
        try:
            value = float(getattr(ds, keyword, default))
        except (TypeError, ValueError):
            value = float("nan")
        if not np.isfinite(value):
            raise ValueError(f"path {str(path)!r}: {keyword} {tag} must be a finite number, "
                             f"got {getattr(ds, keyword, None)!r}")
        rescale.append(value)
    return pixels * rescale[0] + rescale[1]


def _one_frame(image: np.ndarray, frame_index, path: Path) -> np.ndarray:
    if image.ndim == 3:
        if frame_index is None:
            raise ValueError(f"path {str(path)!r} holds {image.shape[0]} frames: pass frame_index= to pick one")
        if frame_index >= image.shape[0]:
            raise ValueError(f"frame_index must be in [0, {image.shape[0]}) for {str(path)!r}, got {frame_index}")
        return image[frame_index]
    if image.ndim != 2:
        raise ValueError(f"path {str(path)!r} holds an image of shape {image.shape}, expected a 2-D frame")
    if frame_index not in (None, 0):
        raise ValueError(f"path {str(path)!r} holds a single frame, got frame_index={frame_index}")
    return image
