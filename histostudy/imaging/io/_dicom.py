"""CBCT volumes in DICOM (§II-A, §II-D): a folder holding one series of slices, or one enhanced multi-frame
file, read into a Volume (LPS mm, HU); unevenly spaced or tilted series are refused (docs/imaging.md,
"Volume files")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..volume import Volume
from ._grid import _axis_aligned_volume, _no_spacing, _require_finite

__all__ = [
    "SLICE_POSITION_RTOL",
]

#: Largest distance of a DICOM slice from the uniform grid through the first and last slice,
#: as a fraction of the slice spacing. Positions are decimal strings that scanners round
#: (often to 0.01 mm); a missing or duplicated slice is off by a whole spacing.
SLICE_POSITION_RTOL = 0.02


@dataclass
class _Slice:
    """One 2-D image with its plane geometry (LPS mm), its values already rescaled."""

    source: str
    pixels: np.ndarray          # (rows, cols) float32, rescaled
    position: np.ndarray        # ImagePositionPatient: centre of pixel (row 0, col 0)
    row_cosine: np.ndarray      # direction of increasing column index
    col_cosine: np.ndarray      # direction of increasing row index
    pixel_spacing: np.ndarray   # [between rows, between columns]


def _numbers(value, count: int) -> np.ndarray | None:
    if value is None or value == "":
        return None
    try:
        arr = np.asarray([float(v) for v in (value if hasattr(value, "__len__") else [value])])
    except (TypeError, ValueError):
        return None
    return arr if arr.shape == (count,) and np.all(np.isfinite(arr)) else None


def _rescale_term(source: str, keyword: str, tag: str, value, default: float) -> float:
    if value is None or value == "":
        return default
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {keyword} {tag} is {value!r}, expected one number") from None
    if not np.isfinite(number):
        raise ValueError(
            f"{source}: {keyword} {tag} is {value!r}, expected a finite number "
            "(the rescale to HU would make every voxel of the slice non-finite)"
        )
    return number


def _rescale(source: str, pixels: np.ndarray, slope, intercept) -> np.ndarray:
    slope = _rescale_term(source, "RescaleSlope", "(0028,1053)", slope, 1.0)
    intercept = _rescale_term(source, "RescaleIntercept", "(0028,1052)", intercept, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below, by slice
        values = (pixels.astype(np.float64) * slope + intercept).astype(np.float32)
    # float pixel data can hold NaN/inf, and a huge slope overflows float32: name the slice now
    _require_finite(values, source)
    return values


def _make_slice(source: str, pixels: np.ndarray, position, orientation, spacing,
                slope, intercept) -> _Slice:
    if spacing is None or (hasattr(spacing, "__len__") and len(spacing) == 0):
        raise _no_spacing(source, "the DICOM tag PixelSpacing (0028,0030) is missing")
    pixel_spacing = _numbers(spacing, 2)
    if pixel_spacing is None or np.any(pixel_spacing <= 0):
        raise _no_spacing(source, f"PixelSpacing (0028,0030) is {spacing!r}, expected two values > 0 mm")
    if position is None or (hasattr(position, "__len__") and len(position) == 0):
        raise _no_spacing(
            source, "the DICOM tag ImagePositionPatient (0020,0032) is missing (slice spacing comes from it)"
        )
    pos = _numbers(position, 3)
    if pos is None:
        raise ValueError(f"{source}: ImagePositionPatient (0020,0032) is {position!r}, expected 3 numbers in mm")
    cos = _numbers(orientation, 6)
    if cos is None:
        raise ValueError(
            f"{source}: ImageOrientationPatient (0020,0037) is missing or malformed ({orientation!r}); "
            "a CBCT volume without orientation has no geometry"
        )
    row_cos, col_cos = cos[:3], cos[3:]
    if pixels.ndim != 2:
        raise ValueError(f"{source}: pixel data of shape {pixels.shape}, expected one monochrome 2-D slice")
    return _Slice(source, _rescale(source, pixels, slope, intercept), pos,
                  row_cos / np.linalg.norm(row_cos), col_cos / np.linalg.norm(col_cos), pixel_spacing)


def _slice_from_dataset(ds, source: str) -> _Slice:
    try:
        pixels = ds.pixel_array
    except Exception as exc:  # missing decoder plugins raise several types; name the file
        raise ValueError(f"{source}: the pixel data could not be decoded (a truncated or corrupt file, or a "
                         f"missing decoder plugin): {exc}") from exc
    return _make_slice(
        source, np.asarray(pixels), ds.get("ImagePositionPatient"), ds.get("ImageOrientationPatient"),
        ds.get("PixelSpacing"), ds.get("RescaleSlope"), ds.get("RescaleIntercept"),
    )


_DEFLATED_TRANSFER_SYNTAX = "1.2.840.10008.1.2.1.99"

# Bulk data elements one of which every image holds; Rows/Columns without any is a cut-off image.
_BULK_DATA = ("PixelData", "FloatPixelData", "DoubleFloatPixelData", "SpectroscopyData")


def _has_dicom_prefix(path: Path) -> bool:
    """Whether ``path`` starts as a DICOM file does: a 128-byte preamble, then ``DICM``."""
    with open(path, "rb") as fh:
        head = fh.read(132)
    return len(head) == 132 and head[128:] == b"DICM"


def _read_dicom(path: Path, stop_before_pixels: bool = False):
    """The pydicom dataset of ``path``, or None where the file is not DICOM at all.

    pydicom reads a file cut short without complaint (it stops at the last whole element, or keeps a
    short value), which would drop a slice from a series unnoticed. A file that starts as DICOM (or
    is named .dcm/.dicom) and cannot be read whole is therefore refused, not skipped.
    ``stop_before_pixels``: read the header only (the checks that need the pixel data are skipped).
    """
    import pydicom
    from pydicom.dataelem import RawDataElement
    from pydicom.errors import InvalidDicomError

    source = f"DICOM file {str(path)!r}"
    try:
        claims_dicom = _has_dicom_prefix(path) or path.suffix.lower() in (".dcm", ".dicom")
        size = path.stat().st_size
    except OSError as exc:
        raise ValueError(f"{source} could not be read: {exc}") from exc
    try:
        ds = pydicom.dcmread(path, stop_before_pixels=stop_before_pixels)
    except Exception as exc:  # a damaged file escapes as struct.error, EOFError, ValueError, ...
        if not claims_dicom and isinstance(exc, (InvalidDicomError, OSError, EOFError)):
            return None  # not DICOM (notes, thumbnails, a DICOMDIR's neighbours): not a slice
        if isinstance(exc, InvalidDicomError):  # pydicom's own text suggests a Python argument
            raise ValueError(f"{source} could not be read as DICOM: it does not start as a DICOM file does (a "
                             f"128-byte preamble, then 'DICM'; {size} bytes in all): truncated, or not a DICOM "
                             "file") from exc
        raise ValueError(
            f"{source} could not be read as DICOM: truncated or corrupt ({type(exc).__name__}: {exc})"
        ) from exc
    tags = ds.keys()
    if not tags:
        raise ValueError(f"{source} is truncated or corrupt: no data set follows its file meta information "
                         f"({size} bytes in all)")
    # Elements are stored in tag order, so the largest tag is the last in the file: past the end
    # of the file its value was cut short; fewer than 8 bytes after it are a cut element header
    # (pydicom stops there silently). An undefined length (a sequence's) cannot be checked this
    # cheaply, and a deflated data set's positions are in the inflated stream, not the file.
    last = ds.get_item(max(tags))
    deflated = str(getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", "")) == _DEFLATED_TRANSFER_SYNTAX
    if (isinstance(last, RawDataElement) and last.length != 0xFFFFFFFF and last.value_tell is not None
            and not deflated):
        end = last.value_tell + last.length
        if end > size or 0 < size - end < 8:  # stopped before the pixels: their header is 8+ bytes
            raise ValueError(
                f"{source} is truncated or corrupt: its last data element {last.tag} ends at byte {end}, "
                f"but the file has {size} bytes"
            )
    # A cut between two whole elements leaves a well-formed but incomplete data set: an image
    # (by its SOP class, kept in the file meta at the start, or by Rows/Columns) without pixels.
    sop_class = (getattr(getattr(ds, "file_meta", None), "MediaStorageSOPClassUID", None)
                 or ds.get("SOPClassUID") or "")
    sop_name = getattr(sop_class, "name", str(sop_class))
    is_image = "Image Storage" in sop_name or "Rows" in ds or "Columns" in ds
    if is_image and not stop_before_pixels and not any(k in ds for k in _BULK_DATA):
        raise ValueError(f"{source} is truncated or corrupt: an image ({sop_name or 'Rows/Columns'}) without "
                         "its pixel data (7FE0,0010)")
    return ds


def _load_dicom_series(folder: Path) -> Volume:
    source = f"DICOM folder {str(folder)!r}"
    files = sorted(p for p in folder.iterdir() if p.is_file())
    datasets = []
    for f in files:
        ds = _read_dicom(f)
        if ds is not None and "PixelData" in ds:
            datasets.append((f, ds))
    if not datasets:
        raise ValueError(f"{source}: none of its {len(files)} files is a DICOM image; expected one series of slices")
    series: dict[str, list[str]] = {}
    for f, ds in datasets:
        series.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append(f.name)
    if len(series) > 1:
        listing = "; ".join(f"{uid or '(no SeriesInstanceUID)'}: {len(names)} files, e.g. {names[0]}"
                            for uid, names in series.items())
        raise ValueError(f"{source} holds {len(series)} DICOM series ({listing}); put each series in its own folder")
    slices = [_slice_from_dataset(ds, f"DICOM file {str(f)!r}") for f, ds in datasets]
    return _stack_slices(slices, source)


# Where an enhanced (multi-frame) image keeps what a single-slice image has at the top level,
# in the argument order of _make_slice.
_FRAME_ATTRIBUTES = (
    ("PlanePositionSequence", "ImagePositionPatient"),
    ("PlaneOrientationSequence", "ImageOrientationPatient"),
    ("PixelMeasuresSequence", "PixelSpacing"),
    ("PixelValueTransformationSequence", "RescaleSlope"),
    ("PixelValueTransformationSequence", "RescaleIntercept"),
)


def _functional_group_value(ds, frame: int, sequence: str, keyword: str):
    """An enhanced-DICOM attribute of one frame: per-frame group first, then shared, then top level."""
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    shared = ds.get("SharedFunctionalGroupsSequence")
    for groups, index in ((per_frame, frame), (shared, 0)):
        if groups and len(groups) > index:
            items = groups[index].get(sequence)
            if items:
                value = items[0].get(keyword)
                if value not in (None, ""):
                    return value
    return ds.get(keyword)


def _load_dicom_multiframe(path: Path) -> Volume:
    source = f"DICOM file {str(path)!r}"
    ds = _read_dicom(path)
    if ds is None:
        raise ValueError(f"{source} could not be read as DICOM: not a DICOM file")
    if "PixelData" not in ds:
        raise ValueError(f"{source} holds no image (no PixelData)")
    n_frames = int(ds.get("NumberOfFrames", 1) or 1)
    if n_frames < 2:
        raise ValueError(
            f"{source} holds a single slice; a CBCT volume is read from the folder of its series "
            "(pass the folder) or from an enhanced multi-frame file"
        )
    try:
        pixels = np.asarray(ds.pixel_array)
    except Exception as exc:  # missing decoder plugins raise several types; name the file
        raise ValueError(f"{source}: the pixel data could not be decoded (a truncated or corrupt file, or a "
                         f"missing decoder plugin): {exc}") from exc
    if pixels.shape[0] != n_frames or pixels.ndim != 3:
        raise ValueError(f"{source}: pixel data of shape {pixels.shape}, expected {n_frames} monochrome frames")
    slices = []
    for i in range(n_frames):
        attrs = [_functional_group_value(ds, i, seq, kw) for seq, kw in _FRAME_ATTRIBUTES]
        slices.append(_make_slice(f"{source} frame {i + 1}", pixels[i], *attrs))
    return _stack_slices(slices, source)


def _stack_slices(slices: list[_Slice], source: str) -> Volume:
    """Sort slices along their normal, check the grid is uniform and unsheared, build the Volume."""
    if len(slices) < 2:
        raise ValueError(f"{source}: {len(slices)} image slice(s); a CBCT volume needs at least 2")
    ref = slices[0]
    for s in slices[1:]:
        if s.pixels.shape != ref.pixels.shape:
            raise ValueError(f"{s.source}: Rows/Columns {s.pixels.shape} differ from {ref.source} {ref.pixels.shape}")
        if not np.allclose(s.pixel_spacing, ref.pixel_spacing, rtol=1e-5, atol=0):
            raise ValueError(f"{s.source}: PixelSpacing {s.pixel_spacing.tolist()} differs from "
                             f"{ref.source} {ref.pixel_spacing.tolist()}")
        if not (np.allclose(s.row_cosine, ref.row_cosine, atol=1e-5)
                and np.allclose(s.col_cosine, ref.col_cosine, atol=1e-5)):
            raise ValueError(f"{s.source}: ImageOrientationPatient "
                             f"{np.r_[s.row_cosine, s.col_cosine].tolist()} differs from {ref.source} "
                             f"{np.r_[ref.row_cosine, ref.col_cosine].tolist()}")
    normal = np.cross(ref.row_cosine, ref.col_cosine)
    norm = np.linalg.norm(normal)
    if norm < 0.5:
        raise ValueError(f"{ref.source}: the row and column cosines of ImageOrientationPatient are not "
                         f"orthogonal ({ref.row_cosine.tolist()}, {ref.col_cosine.tolist()})")
    normal /= norm
    positions = np.array([s.position for s in slices])
    depth = positions @ normal
    order = np.argsort(depth, kind="stable")
    slices = [slices[i] for i in order]
    positions, depth = positions[order], depth[order]
    gaps = np.diff(depth)
    if np.any(gaps <= 0):
        k = int(np.argmin(gaps))
        raise ValueError(f"{source}: {slices[k].source} and {slices[k + 1].source} lie at the same position "
                         f"along the slice normal ({depth[k]:.4f} mm): a duplicated slice or a second series?")
    spacing = (depth[-1] - depth[0]) / (len(slices) - 1)
    deviation = np.abs(depth - (depth[0] + spacing * np.arange(len(slices))))
    if deviation.max() > SLICE_POSITION_RTOL * spacing:
        k = int(np.argmax(deviation))
        raise ValueError(
            f"{source}: the slices are not uniformly spaced along their normal (gaps "
            f"{np.round(gaps, 4).tolist()} mm; {slices[k].source} is {deviation[k]:.4f} mm off a uniform "
            f"{spacing:.4f} mm grid, tolerance {SLICE_POSITION_RTOL:g} of the spacing): a missing slice? "
            "resampling is not done"
        )
    # Slices must stack straight along the normal; an in-plane drift is a gantry tilt (shear).
    in_plane = (positions - positions[0]) - np.outer(depth - depth[0], normal)
    drift = np.linalg.norm(in_plane, axis=1)
    limit = SLICE_POSITION_RTOL * float(ref.pixel_spacing.min())
    if drift.max() > limit:
        k = int(np.argmax(drift))
        raise ValueError(
            f"{source}: {slices[k].source} is shifted {drift[k]:.4f} mm within the slice plane relative to "
            f"{slices[0].source} (tolerance {limit:.4f} mm): a sheared (gantry-tilted) series; resampling is not done"
        )
    data = np.stack([s.pixels for s in slices])  # [slice, row, column]
    steps = np.column_stack([
        normal * spacing,
        ref.col_cosine * ref.pixel_spacing[0],   # next row: along the column cosine, row spacing
        ref.row_cosine * ref.pixel_spacing[1],   # next column: along the row cosine, column spacing
    ])
    # The file's voxel (i, j, k) is (column, row, slice): data axes 2, 1, 0.
    return _axis_aligned_volume(data, steps, positions[0], source, file_axes=(2, 1, 0))
