"""DICOM X-ray angiography (XA) objects written as a C-arm writes them (§II-A, §II-B.2): geometry tags,
detector counts, cine timing; UIDs derived from a seed, so the same seed writes the same bytes."""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path

from ..carm import View

__all__ = ["XA_SOP_CLASS_UID", "detector_counts", "write_xa", "xa_dataset"]

#: X-Ray Angiographic Image Storage (PS3.4 B.5).
XA_SOP_CLASS_UID = "1.2.840.10008.5.1.4.1.1.12.1"


def detector_counts(line_integrals, *, i0: float = 4095.0, bits_stored: int = 12) -> np.ndarray:
    """The counts a detector stores for a line-integral image: ``round(i0 exp(-L))``.

    Args:
        line_integrals: ``(..., rows, cols)`` line integrals ``L`` (dimensionless, a rendered
            :class:`~histostudy.imaging.frame.Frame`'s image), finite.
        i0: the unattenuated count, in ``(0, 2**bits_stored - 1]``.
        bits_stored: the stored bits, an integer in 8..16.

    Returns:
        uint16 counts of ``line_integrals``' shape, clipped to ``bits_stored`` bits.

    Raises:
        ValueError: ``line_integrals`` not finite, or ``i0`` or ``bits_stored`` out of range.
    """
    bits = _bits(bits_stored)
    L = np.asarray(line_integrals, dtype=np.float64)
    if not np.all(np.isfinite(L)):
        raise ValueError("line_integrals must be finite")
    if not (np.isfinite(i0) and 0 < i0 <= 2 ** bits - 1):
        raise ValueError(f"i0 must be in (0, {2 ** bits - 1}] for {bits} bits, got {i0!r}")
    return np.clip(np.round(i0 * np.exp(-L)), 0, 2 ** bits - 1).astype(np.uint16)


def _bits(bits_stored) -> int:
    if isinstance(bits_stored, bool) or not isinstance(bits_stored, (int, np.integer)) or not 8 <= bits_stored <= 16:
        raise ValueError(f"bits_stored must be an integer in 8..16, got {bits_stored!r}")
    return int(bits_stored)


def _uid(uid_seed: str, what: str) -> str:
    from pydicom.uid import generate_uid

    return generate_uid(entropy_srcs=[str(uid_seed), what])


def xa_dataset(view: View, intensities, *, bits_stored: int = 12, uid_seed: str = "histostudy",
               instance_number: int = 1, series_number: int = 1,
               acquisition_time: _dt.datetime | None = None, frame_time_ms: float | None = None,
               patient_id: str = "PHANTOM", study_uid_seed: str | None = None):
    """One XA object (pydicom ``FileDataset``-ready ``Dataset`` with its file meta) holding
    ``intensities`` — ``(rows, cols)`` or a cine ``(n, rows, cols)`` of detector counts in
    ``0 .. 2**bits_stored - 1`` — with ``view``'s geometry tags.

    ``view`` must carry its gantry parameters (made by :meth:`View.from_gantry` or
    :meth:`View.from_dicom`); the object's ``SeriesDescription`` is the view's name (the plane).
    ``acquisition_time``: when the first frame was taken (default 2020-01-01 00:00); a cine gets
    ``FrameTime`` ``frame_time_ms`` (default 66.7 ms, 15 frames/s). ``uid_seed`` and ``view.name``
    make the study, series and instance UIDs, so two planes of one run share a study;
    ``study_uid_seed``, when given, makes the study's instead (the acquisitions of one procedure).
    """
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian

    if not isinstance(view, View):
        raise TypeError(f"view must be a View, got {type(view).__name__}")
    if not view.gantry:
        raise ValueError(f"view {view.name!r} carries no gantry angles and distances (make it with "
                         "View.from_gantry or View.from_dicom): an XA object records its geometry as those tags")
    bits = _bits(bits_stored)
    counts = np.asarray(intensities)
    if counts.ndim not in (2, 3) or counts.shape[-2:] != tuple(view.shape):
        raise ValueError(f"intensities must be (rows, cols) or (n, rows, cols) with (rows, cols) = view "
                         f"{view.name!r}'s shape {tuple(view.shape)}, got shape {counts.shape}")
    if not np.issubdtype(counts.dtype, np.integer) or counts.min() < 0 or counts.max() > 2 ** bits - 1:
        raise ValueError(f"intensities must be integer counts in 0..{2 ** bits - 1} ({bits} bits), got dtype "
                         f"{counts.dtype} in [{counts.min()}, {counts.max()}] (see detector_counts)")
    for name, value in (("instance_number", instance_number), ("series_number", series_number)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    when = acquisition_time or _dt.datetime(2020, 1, 1)
    g = view.gantry
    plane = view.name or "A"

    ds = Dataset()
    ds.file_meta = FileMetaDataset()
    ds.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds.SOPClassUID = XA_SOP_CLASS_UID
    ds.SOPInstanceUID = _uid(uid_seed, f"instance/{plane}/{series_number}/{instance_number}")
    ds.file_meta.MediaStorageSOPClassUID, ds.file_meta.MediaStorageSOPInstanceUID = ds.SOPClassUID, ds.SOPInstanceUID
    ds.StudyInstanceUID = _uid(uid_seed if study_uid_seed is None else study_uid_seed, "study")
    ds.SeriesInstanceUID = _uid(uid_seed, f"series/{plane}/{series_number}")
    ds.Modality, ds.PatientID, ds.PatientName = "XA", patient_id, patient_id
    ds.SeriesDescription, ds.SeriesNumber, ds.InstanceNumber = plane, int(series_number), int(instance_number)
    ds.ContentDate, ds.ContentTime = when.strftime("%Y%m%d"), when.strftime("%H%M%S.%f")
    ds.AcquisitionDateTime = when.strftime("%Y%m%d%H%M%S.%f")
    ds.PositionerPrimaryAngle, ds.PositionerSecondaryAngle = g["primary_deg"], g["secondary_deg"]
    ds.DistanceSourceToPatient, ds.DistanceSourceToDetector = g["source_isocenter_mm"], g["source_detector_mm"]
    ds.ImagerPixelSpacing = [view.pixel_mm, view.pixel_mm]
    ds.Rows, ds.Columns = (int(n) for n in view.shape)
    if counts.ndim == 3:
        ds.NumberOfFrames = len(counts)
        ds.FrameTime = 66.7 if frame_time_ms is None else float(frame_time_ms)
        ds.FrameIncrementPointer = 0x00181063  # FrameTime
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, bits, bits - 1, 0
    ds.PixelData = np.ascontiguousarray(counts, dtype="<u2").tobytes()
    return ds


def write_xa(path: str | os.PathLike, view: View, intensities, **options) -> Path:
    """An XA object written as a C-arm writes it (§II-D): a DICOM Part 10 file, explicit VR little
    endian, written atomically.

    Args:
        path: the file to write.
        view: the C-arm view, with its gantry parameters (made by ``View.from_gantry`` or
            ``View.from_dicom``); its geometry becomes the object's tags, its name the
            ``SeriesDescription``.
        intensities: ``(rows, cols)`` or a cine ``(n, rows, cols)`` of detector counts (pixels), e.g.
            :func:`detector_counts`'s.
        **options: ``bits_stored``, ``uid_seed``, ``instance_number``, ``series_number``,
            ``acquisition_time``, ``frame_time_ms`` (ms), ``patient_id``, ``study_uid_seed`` (see
            ``xa_dataset`` in this module).

    Returns:
        The path written.

    Raises:
        TypeError: ``view`` is not a View.
        ValueError: the view carries no gantry parameters, or ``intensities`` or an option is out of
            range.
        OSError: the file cannot be written.
    """
    ds = xa_dataset(view, intensities, **options)
    path = Path(path)
    with atomic_path(path) as tmp:
        ds.save_as(tmp, enforce_file_format=True)
    return path
