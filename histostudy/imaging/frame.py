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
               air_value: float | None = None) -> Frame:
    """Load a real fluoroscopic frame from ``.npy``, ``.png``/``.tif`` or DICOM (``.dcm``).

    Args:
        path: the image file.
        view: its calibrated geometry (e.g. from :func:`~histostudy.imaging.carm.load_views`).
        line_integrals: True when the file already holds line integrals (as the paper's
            preprocessed projections). False for raw intensities, which are converted with
            ``-log(I / air_value)``.
        air_value: unattenuated intensity ``I0`` for the conversion; default the image maximum.
    """
    path = Path(path)
    suffix = path.suffix.lower()
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
        import pydicom

        ds = pydicom.dcmread(path)
        image = ds.pixel_array.astype(np.float64)
        image = image * float(getattr(ds, "RescaleSlope", 1.0)) + float(getattr(ds, "RescaleIntercept", 0.0))
    else:
        raise ValueError(f"path {str(path)!r}: unknown image format {suffix!r} (expected .npy, .png, .tif, .dcm)")
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 2:
        raise ValueError(f"path {str(path)!r} holds an image of shape {image.shape}, expected a 2-D frame")
    if not line_integrals:
        i0 = float(image.max()) if air_value is None else float(air_value)
        if not np.isfinite(i0) or i0 <= 0:
            raise ValueError(f"air_value must be a positive intensity, got {air_value!r}")
        image = -np.log(np.clip(image, 1e-6 * i0, None) / i0)
    return Frame(image=image.astype(np.float32), view=view, meta={"source": str(path)})
