"""The one check of a DICOM X-ray object that every reader of the lab's frames applies (SOP class, transfer
syntax, lossless pixels, image size), and the decoding of its pixels; refusals carry the C-STORE status
(docs/imaging.md, "X-ray objects")."""

from __future__ import annotations

__all__ = ["RECEIVABLE_TRANSFER_SYNTAXES", "X_RAY_SOP_CLASSES", "XRayObjectRejected", "check_sop_class",
           "check_xray_object", "read_dicom_file", "stored_sop_class", "xray_pixels"]

#: The SOP classes whose frames are read (the others are refused; C-STORE status 0x0122).
X_RAY_SOP_CLASSES = {
    "1.2.840.10008.5.1.4.1.1.12.1": "X-Ray Angiographic Image Storage",
    "1.2.840.10008.5.1.4.1.1.12.1.1": "Enhanced XA Image Storage",
    "1.2.840.10008.5.1.4.1.1.12.2": "X-Ray Radiofluoroscopic Image Storage",
}

STATUS_SOP_CLASS_NOT_SUPPORTED = 0x0122
STATUS_DATASET_MISMATCH = 0xA900
STATUS_CANNOT_UNDERSTAND = 0xC000

#: Native (uncompressed) transfer syntaxes: implicit and explicit VR little endian, deflated
#: explicit VR little endian, explicit VR big endian (retired, still sent by old equipment).
_NATIVE = ("1.2.840.10008.1.2.1", "1.2.840.10008.1.2", "1.2.840.10008.1.2.1.99", "1.2.840.10008.1.2.2")
#: The compressed ones read where pydicom has a decoder for them.
_COMPRESSED = (
    "1.2.840.10008.1.2.4.70",  # JPEG Lossless, first-order prediction (process 14, selection value 1)
    "1.2.840.10008.1.2.4.57",  # JPEG Lossless (process 14)
    "1.2.840.10008.1.2.4.80",  # JPEG-LS Lossless
    "1.2.840.10008.1.2.4.81",  # JPEG-LS near-lossless: read when its stream's NEAR is 0
    "1.2.840.10008.1.2.4.90",  # JPEG 2000 (lossless only)
    "1.2.840.10008.1.2.4.91",  # JPEG 2000: read when its stream is reversible
    "1.2.840.10008.1.2.5",     # RLE Lossless
)
#: Syntaxes refused on purpose, with why.
_REFUSED = {
    "1.2.840.10008.1.2.4.50": "lossy JPEG (baseline) is refused: its 8x8 blocks edit the edges the pose is "
                              "found from; send JPEG Lossless, JPEG-LS, JPEG 2000 or RLE",
    "1.2.840.10008.1.2.4.51": "lossy JPEG (extended) is refused: its 8x8 blocks edit the edges the pose is "
                              "found from; send JPEG Lossless, JPEG-LS, JPEG 2000 or RLE",
}


def _receivable() -> tuple[str, ...]:
    from pydicom.pixels import get_decoder

    return _NATIVE + tuple(uid for uid in _COMPRESSED if get_decoder(uid).is_available)


#: The transfer syntaxes whose pixels the readers decode in this install, native first: what the
#: live receiver accepts at association negotiation and what a file may be stored in.
RECEIVABLE_TRANSFER_SYNTAXES: tuple[str, ...] = _receivable()


class XRayObjectRejected(ValueError):
    """A DICOM object the readers refuse: ``status`` is the C-STORE failure status the receiver
    answers (:data:`histostudy.lab.REJECTION_STATUSES`), the message the reason."""

    def __init__(self, status: int, reason: str):
        super().__init__(reason)
        self.status = int(status)
        self.reason = reason


def _named(uid: str) -> str:
    from pydicom.uid import UID

    name = UID(uid).name if uid else ""
    return f"{uid or '(none)'}" + (f" ({name})" if name and name != uid else "")


def check_sop_class(sop_class_uid, *, stored=None, source: str | None = None) -> None:
    """Refuses an object that is not an X-ray image.

    Args:
        sop_class_uid: the data set's SOPClassUID; None or empty, with ``stored`` None, is a bare
            image and is not refused.
        stored: the SOP class it was stored as (a C-STORE's affected SOP class, a Part 10 file's
            MediaStorageSOPClassUID: :func:`stored_sop_class`), or None.
        source: what the message starts with (e.g. ``"path 'A.dcm'"``), or None.

    Returns:
        None.

    Raises:
        XRayObjectRejected: the class (``stored``, else ``sop_class_uid``) is not in
            :data:`X_RAY_SOP_CLASSES` (status 0x0122), or the two differ (0xA900).
    """
    prefix = "" if not source else f"{source}: "
    sop = str(sop_class_uid or "")
    expected = sop if stored is None else str(stored or "")
    if stored is None and not sop:
        return
    if expected not in X_RAY_SOP_CLASSES:
        raise XRayObjectRejected(STATUS_SOP_CLASS_NOT_SUPPORTED,
                                 f"{prefix}SOP class {_named(expected)} is not an X-ray angiographic or RF image; "
                                 f"this reader takes {', '.join(X_RAY_SOP_CLASSES.values())}")
    if not sop:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}the data set names no SOPClassUID (0008,0016), "
                                                          f"which an object stored as {expected} must")
    if sop != expected:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}the data set's SOPClassUID {sop} "
                                                          f"differs from the stored SOP class {expected}")


def stored_sop_class(ds):
    """The SOP class a data set read from a file was stored as: its file meta's
    MediaStorageSOPClassUID (0002,0002), or None for a data set without one (written by a script
    with no file meta: a bare image, whose tags are read as they are).

    Args:
        ds: the pydicom data set.

    Returns:
        The UID as a string, or None.
    """
    stored = getattr(getattr(ds, "file_meta", None), "MediaStorageSOPClassUID", None)
    return str(stored) if stored else None


def _check_transfer_syntax(ds, prefix: str) -> str:
    try:
        syntax = str(ds.file_meta.TransferSyntaxUID)
    except AttributeError:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}its pixel data cannot be read: no file meta "
                                                          "TransferSyntaxUID (0002,0010)") from None
    if syntax in RECEIVABLE_TRANSFER_SYNTAXES:
        return syntax
    if syntax in _REFUSED:
        why = _REFUSED[syntax]
    elif syntax in _COMPRESSED:
        from pydicom.pixels import get_decoder

        why = "pydicom has no decoder for it in this install (" + "; ".join(
            get_decoder(syntax).missing_dependencies) + ")"
    else:
        why = "not one this reader decodes"
    raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}its pixel data cannot be read: transfer syntax "
                                                      f"{_named(syntax)}: {why}")


def _lossy(ds, syntax: str) -> str | None:
    """Why the object's pixels are lossy (module docstring), or None; a stream read from its first frame."""
    if str(getattr(ds, "LossyImageCompression", "") or "").strip() == "01":
        return "its LossyImageCompression (0028,2110) is 01: its pixels were compressed lossily"
    if syntax not in ("1.2.840.10008.1.2.4.81", "1.2.840.10008.1.2.4.91"):
        return None
    from pydicom.encaps import generate_frames

    try:
        stream = next(generate_frames(ds.PixelData, number_of_frames=int(getattr(ds, "NumberOfFrames", 1) or 1)))
    except Exception:  # an unreadable stream is refused where it is decoded (xray_pixels)
        return None
    if syntax.endswith(".81"):  # JPEG-LS: NEAR follows the scan's components in its SOS segment
        at = stream.find(b"\xff\xda")
        end = at + 5 + 2 * stream[at + 4] if 0 <= at < len(stream) - 4 else -1
        near = stream[end] if 0 <= end < len(stream) else 0
        return f"its JPEG-LS stream is near-lossless (NEAR {near}): send it lossless" if near else None
    at = stream.find(b"\xff\x52")  # JPEG 2000 COD: the wavelet transform, 0 = irreversible 9-7
    if 0 <= at and len(stream) > at + 13 and stream[at + 13] == 0:
        return "its JPEG 2000 stream is irreversible (9-7 wavelet): send it reversible (lossless)"
    return None


def check_xray_object(ds, *, sop_class_uid=None, source: str | None = None) -> None:
    """The checks every reader of an X-ray object applies before its pixels (docs/imaging.md, "X-ray
    objects"): the SOP class (:func:`check_sop_class`), the transfer syntax, lossless pixels, the
    image size, one sample per pixel and the pixel data's length (native) or, compressed, a
    fragment for each frame declared.

    Args:
        ds: the pydicom data set.
        sop_class_uid: the SOP class it was stored as (a C-STORE's), or None: the file meta's
            (:func:`stored_sop_class`).
        source: what the message starts with, or None.

    Returns:
        None.

    Raises:
        XRayObjectRejected: with the C-STORE status and the reason, starting with ``source``.
    """
    from pydicom.pixels.utils import get_expected_length

    prefix = "" if not source else f"{source}: "
    stored = sop_class_uid if sop_class_uid is not None else stored_sop_class(ds)
    check_sop_class(getattr(ds, "SOPClassUID", None), stored=stored, source=source)
    syntax = _check_transfer_syntax(ds, prefix)
    if (lossy := _lossy(ds, syntax)) is not None:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}lossy pixels are refused: {lossy}")
    try:
        n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        rows, cols = int(ds.Rows), int(ds.Columns)
    except (AttributeError, TypeError, ValueError) as exc:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}no readable image size (Rows, Columns, "
                                                          f"NumberOfFrames): {exc}") from None
    samples = int(getattr(ds, "SamplesPerPixel", 1) or 1)
    if samples != 1:
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, f"{prefix}SamplesPerPixel (0028,0002) is {samples}; "
                                                           "X-ray frames must be greyscale (1)")
    try:
        data = ds.PixelData
        expected = get_expected_length(ds, "bytes") if syntax in _NATIVE else None
    except Exception as exc:  # no PixelData, a pixel module pydicom cannot size
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"{prefix}its pixel data cannot be read: {type(exc).__name__}: {exc}") from None
    if expected is not None and len(data) < expected:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"{prefix}its pixel data cannot be read: PixelData holds {len(data)} bytes, its "
                                 f"{n_frames} frame(s) of {rows} x {cols} need {expected}")
    if expected is not None and len(data) > expected + expected % 2:  # beyond an odd length's padding byte
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"{prefix}its pixel data is corrupt: PixelData holds {len(data)} bytes, more than "
                                 f"its {n_frames} frame(s) of {rows} x {cols} (Rows, Columns, NumberOfFrames) "
                                 f"take, {expected}")
    if syntax not in _NATIVE and n_frames > 1:
        _check_fragments(data, n_frames, prefix)


def _check_fragments(data: bytes, n_frames: int, prefix: str) -> None:
    """Refuses (0xA900) encapsulated (compressed) pixel data with fewer fragments than the frames it
    declares: each fragment holds one frame's data at most (PS3.5 §A.4), and, unlike native pixels,
    no length bounds a compressed object's NumberOfFrames (a few bytes may declare 2**30 frames)."""
    from pydicom.encaps import parse_fragments

    try:
        fragments = parse_fragments(data)[0] - 1  # the first item is the Basic Offset Table
    except Exception as exc:  # items pydicom cannot walk
        fragments, why = 0, f": {type(exc).__name__}: {exc}"
    else:
        why = ""
    if fragments < n_frames:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}its pixel data cannot be read: NumberOfFrames is "
                                                          f"{n_frames}, its encapsulated pixel data holds {fragments} "
                                                          f"fragment(s){why}")


def read_dicom_file(path, *, stop_before_pixels: bool = False):
    """The pydicom data set of a DICOM file, every failure naming the file and what is wrong (pydicom
    reads a file cut short without complaint and words its own errors without the file's name).

    Args:
        path: the file.
        stop_before_pixels: read its header only.

    Returns:
        The pydicom data set.

    Raises:
        FileNotFoundError: no such file.
        IsADirectoryError: ``path`` is a folder.
        ValueError: not DICOM, truncated or corrupt.
    """
    from pathlib import Path

    from ._dicom import _read_dicom

    path = Path(path)
    source = f"DICOM file {str(path)!r}"
    if path.is_dir():
        raise IsADirectoryError(f"{source} is a folder, not a file")
    if not path.is_file():
        raise FileNotFoundError(f"{source}: no such file")
    ds = _read_dicom(path, stop_before_pixels)
    if ds is None:  # a name without .dcm/.dicom and no DICM prefix: _read_dicom's "not DICOM at all"
        raise ValueError(f"{source} could not be read as DICOM: it does not start as a DICOM file does (a 128-byte "
                         "preamble, then 'DICM'): not a DICOM file")
    return ds


def xray_pixels(ds, frame_index: int | None = None, *, source: str | None = None):
    """The stored values of an X-ray object, decoded by pydicom's plugin for its transfer syntax.

    Args:
        ds: the pydicom data set (checked with :func:`check_xray_object` first).
        frame_index: the frame to decode, or None for every frame.
        source: what the message starts with, or None.

    Returns:
        ``(rows, cols)`` for one frame; for None, ``(frames, rows, cols)``, or ``(rows, cols)`` for a
        single-frame object (pixels, the stored dtype).

    Raises:
        XRayObjectRejected: (0xA900) a stream that does not decode or decodes to another size.
    """
    import numpy as np
    from pydicom.pixels import get_decoder

    prefix = "" if not source else f"{source}: "
    rows, cols = int(ds.Rows), int(ds.Columns)
    try:
        pixels, _ = get_decoder(ds.file_meta.TransferSyntaxUID).as_array(ds, index=frame_index)
    except Exception as exc:  # pydicom and its plugins raise several kinds for a broken stream
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"{prefix}its pixel data cannot be read: {type(exc).__name__}: {exc}") from None
    pixels = np.asarray(pixels)
    if frame_index is not None and pixels.size != rows * cols:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"{prefix}frame {frame_index}'s pixel data decode to "
                                                          f"shape {pixels.shape}, not {rows} x {cols}")
    return pixels.reshape(rows, cols) if frame_index is not None else pixels
