"""Real CBCT volumes from disk: NIfTI (read and write) and DICOM (a folder of slices, or one
enhanced multi-frame file), as :class:`~histostudy.imaging.volume.Volume`.

Paper sections: §II-A (a CBCT is a voxel grid whose value between voxel centres is the trilinear
interpolation, :meth:`Volume.sample`), §II-D (the pre-treatment CBCT in which the target is picked
and the post-treatment CBCT in which the treated zone is segmented). The synthetic study makes
these volumes with :func:`~histostudy.imaging.cbct.simulate_cbct`; this module lets the lab's own
volumes take their place in the same code path.

Frames and units: the world frame is the CBCT/C-arm frame in DICOM patient coordinates (LPS:
+x towards the patient's left, +y posterior, +z superior), millimetres. A :class:`Volume` is
axis-aligned with that frame, has positive spacing along +x, +y, +z, and its ``origin_mm`` is the
world position of the centre of voxel ``[0, 0, 0]``; its data are float32, indexed ``[z, y, x]``,
in Hounsfield units for CT (DICOM rescale and NIfTI ``scl_slope``/``scl_inter`` are applied).

A file whose grid is axis-aligned in any order or direction (a signed permutation of the LPS
axes) is reordered and flipped onto that layout without touching a value. An oblique grid, a
sheared series (gantry tilt) or unevenly spaced slices are refused: resampling would interpolate
the gray values the treatment-zone segmentation (§II-E.3) measures, so it is left to the user,
done once and knowingly.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path
from .volume import Volume

__all__ = [
    "AXIS_TOLERANCE",
    "SLICE_POSITION_RTOL",
    "SUPPORTED_FORMATS",
    "load_volume",
    "save_volume_nifti",
]

#: Largest off-axis component of a unit direction cosine still read as axis-aligned. Files store
#: cosines as float32 (NIfTI) or decimal strings (DICOM), so exact zeros cannot be required.
AXIS_TOLERANCE = 1e-6

#: Largest distance of a DICOM slice from the uniform grid through the first and last slice,
#: as a fraction of the slice spacing. Positions are decimal strings that scanners round
#: (often to 0.01 mm); a missing or duplicated slice is off by a whole spacing.
SLICE_POSITION_RTOL = 0.02

#: What :func:`load_volume` reads (for error messages and documentation).
SUPPORTED_FORMATS = (
    "NIfTI (.nii, .nii.gz); a folder holding one DICOM series of single-slice images; "
    "an enhanced multi-frame DICOM file (.dcm, .dicom)"
)

# RAS (NIfTI) <-> LPS (DICOM, our world frame): x and y change sign, z is shared.
_RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0])

# NIfTI spatial units -> mm; 'unknown' is read as mm, as every common tool does.
_NIFTI_UNIT_TO_MM = {"mm": 1.0, "unknown": 1.0, "meter": 1000.0, "micron": 1e-3}


# ---------------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------------


def load_volume(path: str | os.PathLike) -> Volume:
    """Read a CBCT volume (§II-A, §II-D) into a :class:`Volume` in the LPS C-arm frame (mm, HU).

    Dispatch on ``path``: a ``.nii``/``.nii.gz`` file is NIfTI (read with nibabel); a folder is a
    DICOM series (every file in it that pydicom reads as an image; one series only); a
    ``.dcm``/``.dicom`` file is an enhanced multi-frame DICOM image. See the module docstring
    for what is reoriented and what is refused.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: an unsupported format, or a file whose geometry cannot be read without
            resampling (oblique, sheared, unevenly spaced) or is missing (no spacing/position).
    """
    path = Path(path)
    name = path.name.lower()
    if path.is_dir():
        return _load_dicom_series(path)
    if name.endswith((".nii", ".nii.gz")):
        _require_file(path)
        return _load_nifti(path)
    if name.endswith((".dcm", ".dicom")):
        _require_file(path)
        return _load_dicom_multiframe(path)
    raise ValueError(f"path {str(path)!r}: unsupported CBCT volume format; supported: {SUPPORTED_FORMATS}")


def save_volume_nifti(volume: Volume, path: str | os.PathLike) -> Path:
    """Write ``volume`` to ``path`` (``.nii`` or ``.nii.gz``) atomically; returns the path.

    The data are stored as float32 without scaling and the affine maps voxel indices to RAS mm
    (the LPS world frame with x and y negated), so :func:`load_volume` gives back the same data,
    spacing and origin bit for bit. NIfTI-1 keeps its affine in float32; when the spacing or
    origin is not exactly a float32 the file is written as NIfTI-2 (float64 affine) instead,
    so the round trip stays exact. Nothing is ever half-written: the file is written beside
    ``path`` under a temporary name and renamed into place.
    """
    import nibabel as nib

    if not isinstance(volume, Volume):
        raise TypeError(f"volume must be a histostudy.imaging.volume.Volume, got {type(volume).__name__}")
    path = Path(path)
    name = path.name.lower()
    if name.endswith(".nii.gz"):
        suffix = ".nii.gz"
    elif name.endswith(".nii"):
        suffix = ".nii"
    else:
        raise ValueError(f"path {str(path)!r}: a NIfTI volume is written to .nii or .nii.gz")
    affine = np.eye(4)
    affine[:3, :3] = _RAS_TO_LPS @ np.diag(volume.spacing_mm)
    affine[:3, 3] = _RAS_TO_LPS @ volume.origin_mm
    exact_in_float32 = np.array_equal(affine.astype(np.float32).astype(np.float64), affine)
    image_class = nib.Nifti1Image if exact_in_float32 else nib.Nifti2Image
    # nibabel indexes (i, j, k) = (x, y, z); the Volume is [z, y, x].
    data = np.ascontiguousarray(volume.data.transpose(2, 1, 0), dtype=np.float32)
    img = image_class(data, affine)
    img.set_data_dtype(np.float32)
    # 'scanner' (code 1): the coordinates are the CBCT scanner's own frame, not a template's.
    img.set_sform(affine, code=1)
    img.set_qform(affine, code=1)
    img.header.set_xyzt_units(xyz="mm")
    with atomic_path(path, suffix=suffix) as tmp:
        nib.save(img, tmp)
    return path


# ---------------------------------------------------------------------------------------------
# Axis-aligned grids
# ---------------------------------------------------------------------------------------------


def _require_file(path: Path) -> None:
    if not path.is_file():
        raise FileNotFoundError(f"CBCT volume {str(path)!r} does not exist (or is not a file)")


def _no_spacing(source: str, detail: str) -> ValueError:
    return ValueError(f"{source}: a CBCT volume without spacing has no geometry: {detail}")


def _axis_aligned_volume(data: np.ndarray, steps_lps: np.ndarray, origin_lps: np.ndarray,
                         source: str) -> Volume:
    """The :class:`Volume` of a 3-D array whose axis ``a`` steps by ``steps_lps[:, a]`` (LPS mm).

    ``origin_lps`` is the LPS position of ``data[0, 0, 0]``. The step matrix must be a signed
    permutation times positive scales; axes are flipped and transposed (no value is changed)
    so that the Volume runs along +x, +y, +z.
    """
    steps = np.asarray(steps_lps, dtype=np.float64)
    lengths = np.linalg.norm(steps, axis=0)
    if not np.all(np.isfinite(steps)) or np.any(lengths <= 0):
        raise _no_spacing(source, f"voxel step lengths {lengths.tolist()} mm, expected > 0")
    cosines = steps / lengths
    world_axis = np.argmax(np.abs(cosines), axis=0)
    off_axis = np.abs(cosines).copy()
    off_axis[world_axis, np.arange(3)] = 0.0
    if sorted(world_axis.tolist()) != [0, 1, 2] or off_axis.max() > AXIS_TOLERANCE:
        cos_text = "; ".join(
            f"axis {a}: ({', '.join(f'{c:+.6f}' for c in cosines[:, a])})" for a in range(3)
        )
        raise ValueError(
            f"{source}: the voxel grid is oblique to the LPS world axes (direction cosines of the "
            f"data axes, LPS: {cos_text}; tolerance {AXIS_TOLERANCE}); resampling is not done: "
            "resample the volume onto an axis-aligned grid first"
        )
    origin = np.asarray(origin_lps, dtype=np.float64).copy()
    # The snapped on-axis step is kept, not the vector length: sqrt of a sum of squares would
    # perturb the last bit of the spacing and break exact round trips.
    signed = steps[world_axis, np.arange(3)]
    for a in range(3):
        if signed[a] < 0:
            origin[world_axis[a]] += signed[a] * (data.shape[a] - 1)
            data = np.flip(data, axis=a)
    array_axis_of = [int(np.flatnonzero(world_axis == w)[0]) for w in range(3)]
    data = np.transpose(data, (array_axis_of[2], array_axis_of[1], array_axis_of[0]))
    spacing = np.abs(signed[array_axis_of])
    return Volume(np.ascontiguousarray(data, dtype=np.float32), spacing, origin)


# ---------------------------------------------------------------------------------------------
# NIfTI
# ---------------------------------------------------------------------------------------------


def _load_nifti(path: Path) -> Volume:
    import nibabel as nib
    from nibabel.openers import ImageOpener

    source = f"NIfTI file {str(path)!r}"
    try:
        img = nib.load(str(path))
    except Exception as exc:  # nibabel raises many types for a damaged file; one message for all
        raise ValueError(f"{source} could not be read as NIfTI: {exc}") from exc
    if not isinstance(img, nib.Nifti1Image):
        raise ValueError(f"{source} is a {type(img).__name__}, expected a NIfTI-1/NIfTI-2 image")
    hdr = img.header
    # nibabel silently "fixes" a zero pixdim to 1 on load (a 1 mm grid nobody measured), so the
    # voxel sizes are checked in the header as written.
    with ImageOpener(str(path)) as fh:
        raw_hdr = type(hdr).from_fileobj(fh, check=False)
    shape = tuple(int(n) for n in img.shape)
    if len(shape) < 3 or any(n != 1 for n in shape[3:]):
        raise ValueError(
            f"{source} has shape {shape}; expected a 3-D volume (a 4-D image only with a last axis of length 1)"
        )
    zooms = [float(z) for z in raw_hdr["pixdim"][1:4]]
    # A negative pixdim is an old ANALYZE habit (the sign is the affine's business); zero is no size.
    if not all(np.isfinite(z) and z != 0 for z in zooms):
        raise _no_spacing(source, f"the header's voxel sizes (pixdim[1:4]) are {zooms}, expected non-zero mm")
    if int(hdr["sform_code"]) == 0 and int(hdr["qform_code"]) == 0:
        warnings.warn(
            f"{source} has neither an sform nor a qform (both codes 0): its position in the C-arm "
            "frame is unknown; nibabel's fallback affine (pixdim sizes, centred grid) is used",
            stacklevel=3,
        )
    unit = hdr.get_xyzt_units()[0]
    if unit not in _NIFTI_UNIT_TO_MM:
        raise ValueError(f"{source}: unsupported spatial unit {unit!r} (expected mm, meter or micron)")
    affine = np.asarray(img.affine, dtype=np.float64) * _NIFTI_UNIT_TO_MM[unit]
    # get_fdata applies scl_slope/scl_inter; float32 is the Volume's type, so no float64 copy.
    data = np.asarray(img.get_fdata(caching="unchanged", dtype=np.float32))
    data = data.reshape(shape[:3])
    steps_lps = _RAS_TO_LPS @ affine[:3, :3]
    origin_lps = _RAS_TO_LPS @ affine[:3, 3]
    return _axis_aligned_volume(data, steps_lps, origin_lps, source)


# ---------------------------------------------------------------------------------------------
# DICOM
# ---------------------------------------------------------------------------------------------


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


def _rescale(pixels: np.ndarray, slope, intercept) -> np.ndarray:
    slope = 1.0 if slope in (None, "") else float(slope)
    intercept = 0.0 if intercept in (None, "") else float(intercept)
    return (pixels.astype(np.float64) * slope + intercept).astype(np.float32)


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
    return _Slice(source, _rescale(pixels, slope, intercept), pos,
                  row_cos / np.linalg.norm(row_cos), col_cos / np.linalg.norm(col_cos), pixel_spacing)


def _slice_from_dataset(ds, source: str) -> _Slice:
    try:
        pixels = ds.pixel_array
    except Exception as exc:  # missing decoder plugins raise several types; name the file
        raise ValueError(f"{source}: the pixel data could not be decoded: {exc}") from exc
    return _make_slice(
        source, np.asarray(pixels), ds.get("ImagePositionPatient"), ds.get("ImageOrientationPatient"),
        ds.get("PixelSpacing"), ds.get("RescaleSlope"), ds.get("RescaleIntercept"),
    )


def _load_dicom_series(folder: Path) -> Volume:
    import pydicom
    from pydicom.errors import InvalidDicomError

    source = f"DICOM folder {str(folder)!r}"
    files = sorted(p for p in folder.iterdir() if p.is_file())
    datasets = []
    for f in files:
        try:
            ds = pydicom.dcmread(f)
        except (InvalidDicomError, OSError, EOFError):
            continue  # not DICOM (notes, thumbnails, a DICOMDIR's neighbours): not a slice
        if "PixelData" in ds:
            datasets.append((f, ds))
    if not datasets:
        raise ValueError(f"{source}: none of its {len(files)} files is a DICOM image; expected one series of slices")
    series = {}
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
    import pydicom
    from pydicom.errors import InvalidDicomError

    source = f"DICOM file {str(path)!r}"
    try:
        ds = pydicom.dcmread(path)
    except (InvalidDicomError, OSError, EOFError) as exc:
        raise ValueError(f"{source} could not be read as DICOM: {exc}") from exc
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
        raise ValueError(f"{source}: the pixel data could not be decoded: {exc}") from exc
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
    return _axis_aligned_volume(data, steps, positions[0], source)
