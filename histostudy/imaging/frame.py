"""Fluoroscopic frames (§II-B.2): an image of line integrals with its view, and, for a synthetic frame, its
reference labels and true pose; real frames loaded from disk; and the one conversion of a detector's
stored values into line integrals ``-log(I / I0)``."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from histostudy.geometry import check_rigid
from histostudy.transducer import check_label_image

from .carm import View

__all__ = ["Frame", "line_integrals_from_pixels", "load_frame"]


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
            raise ValueError(f"image shape {image.shape} does not match view {self.view.name!r} "
                             f"shape {self.view.shape}")
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

    def with_view(self, view: View) -> Frame:
        """The same image, labels and truth under another geometry: what an estimator given a
        lab's (imperfect) calibration of the C-arm sees. Returns ``self`` for the same view."""
        if view is self.view:
            return self
        return dataclasses.replace(self, view=view)


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

    DICOM: the object must be an X-ray image in a transfer syntax this install decodes
    (:func:`~histostudy.imaging.io.check_xray_object`, which the live receiver applies too: a refusal
    is an :class:`~histostudy.imaging.io.XRayObjectRejected`, a ValueError); the stored values are
    inverted first for ``MONOCHROME1`` (low values white), so that a larger value is always more
    X-ray intensity; then ``RescaleSlope`` / ``RescaleIntercept``
    (finite, or refused naming the tag) give the modality values
    (:func:`line_integrals_from_pixels`, which also makes the line integrals).
    """
    path = Path(path)
    source = f"path {str(path)!r}"
    suffix = path.suffix.lower()
    if frame_index is not None and (isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer))
                                    or frame_index < 0):
        raise ValueError(f"frame_index must be an integer >= 0 or None, got {frame_index!r}")
    dataset = None
    if suffix == ".npy":
        image = np.load(path, allow_pickle=False)
    elif suffix in (".png", ".tif", ".tiff"):
        import cv2

        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{source} could not be read as an image")
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif suffix in (".dcm", ".dicom", ""):
        from .io import check_xray_object, read_dicom_file, xray_pixels

        dataset = read_dicom_file(path)  # pydicom's failures, named with the file
        check_xray_object(dataset, source=source)  # the receiver's check: the same objects refused alike
        image = xray_pixels(dataset, source=source)
    else:
        raise ValueError(f"{source}: unknown image format {suffix!r} (expected .npy, .png, .tif, .dcm)")
    image = _modality_values(_one_frame(np.asarray(image, dtype=np.float64), frame_index, path), dataset, source)
    if image.shape != view.shape:
        if not resample:
            raise ValueError(f"{source} holds a {image.shape} image, the view {view.name!r} expects "
                             f"{view.shape}: pass resample=True to resize it onto the view")
        import cv2

        shrink = image.shape[0] > view.shape[0] or image.shape[1] > view.shape[1]
        image = cv2.resize(image, (view.shape[1], view.shape[0]),
                           interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if not line_integrals:
        image = line_integrals_from_pixels(image, air_value=air_value, source=source)
    meta = {"source": str(path)} | ({} if frame_index is None else {"frame_index": int(frame_index)})
    return Frame(image=image.astype(np.float32), view=view, meta=meta)


def line_integrals_from_pixels(pixels, dataset=None, *, air_value: float | None = None,
                               source: str | None = None) -> np.ndarray:
    """Line integrals ``-log(I / I0)`` (float32, dimensionless) of a detector's stored values.

    Args:
        pixels: ``(rows, cols)`` or ``(frames, rows, cols)`` stored values (a DICOM object's
            ``pixel_array``; counts or intensities).
        dataset: where the values' pixel module is read: a pydicom ``Dataset`` or any object with
            its attributes. ``PhotometricInterpretation`` ``MONOCHROME1`` inverts the values
            (``2**BitsStored - 1 - value``, ``BitsAllocated`` then 16 without ``BitsStored``), so
            that a larger value is more X-ray intensity; ``RescaleSlope`` (0028,1053) and
            ``RescaleIntercept`` (0028,1052) (default 1 and 0; finite, or refused naming the tag)
            then give the modality values ``I``. None: the values are intensities already.
        air_value: the unattenuated intensity ``I0`` (modality units), finite and > 0; None: each
            frame's maximum.
        source: what the values are, to start error messages with (e.g. ``"path 'A.dcm'"``).

    Intensities below ``1e-6 I0`` are clipped there (a line integral of at most ``log(1e6)``).

    Raises:
        ValueError: naming the bad tag or argument, or the frame that holds no signal (its
            maximum, ``I0``, not > 0).
    """
    prefix = "" if source is None else f"{source}: "
    if air_value is not None and (isinstance(air_value, bool) or not isinstance(air_value, (int, float, np.number))
                                  or not math.isfinite(air_value) or air_value <= 0):
        raise ValueError(f"{prefix}air_value must be None or a finite intensity > 0, got {air_value!r}")
    values = np.asarray(pixels)
    if values.ndim not in (2, 3) or not (np.issubdtype(values.dtype, np.number) and values.dtype.kind != "c"):
        raise ValueError(f"{prefix}pixels must be a real (rows, cols) or (frames, rows, cols) array, got shape "
                         f"{values.shape} dtype {values.dtype}")
    values = _modality_values(values.astype(np.float64), dataset, source)
    frames = values.reshape((-1,) + values.shape[-2:])
    out = np.empty(frames.shape, dtype=np.float32)
    for i, frame in enumerate(frames):
        i0 = float(frame.max()) if air_value is None else float(air_value)
        if not (math.isfinite(i0) and i0 > 0):
            raise ValueError(f"{prefix}frame {i} holds no X-ray signal (I0 = its maximum = {i0!r}); give air_value")
        out[i] = -np.log(np.clip(frame, 1e-6 * i0, None) / i0)
    return out.reshape(values.shape)


def _modality_values(pixels: np.ndarray, dataset, source: str | None) -> np.ndarray:
    """The stored values as modality values: MONOCHROME1 inverted, rescale applied
    (:func:`line_integrals_from_pixels`'s ``dataset``); unchanged for ``dataset`` None."""
    if dataset is None:
        return pixels
    prefix = "" if source is None else f"{source}: "
    if str(getattr(dataset, "PhotometricInterpretation", "MONOCHROME2")).strip() == "MONOCHROME1":
        raw = getattr(dataset, "BitsStored", getattr(dataset, "BitsAllocated", 16))
        try:
            bits = int(raw)
        except (TypeError, ValueError):
            bits = 0
        if not 1 <= bits <= 32:
            raise ValueError(f"{prefix}BitsStored (0028,0101) must be an integer in 1..32, got {raw!r}")
        pixels = (2.0 ** bits - 1.0) - pixels
    rescale = []
    for keyword, tag, default in (("RescaleSlope", "(0028,1053)", 1.0), ("RescaleIntercept", "(0028,1052)", 0.0)):
        raw = getattr(dataset, keyword, default)
        try:
            value = float(raw)
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            raise ValueError(f"{prefix}{keyword} {tag} must be a finite number, got {raw!r}")
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
