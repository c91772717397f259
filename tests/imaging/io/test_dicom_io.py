"""DICOM CBCT volumes (histostudy.imaging.io._dicom, read through load_volume): series of slices and
enhanced multi-frame files, their geometry and HU, refused series, and a round trip through NIfTI.

Every geometry test checks values at world points against a ground truth computed independently
from the file's own convention (DICOM position + index * spacing * cosine), so a swapped axis, a
lost flip or a half-voxel shift fails, not only a wrong shape.
"""

import random

import numpy as np
import pydicom
import pytest
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid

from histostudy.imaging import load_volume, save_volume_nifti

CT_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.2"
ENHANCED_CT_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.2.1"


def _file_meta(sop_class: str, sop_instance: str) -> FileMetaDataset:
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = sop_instance
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    return meta


def _pixel_module(ds, rows: int, cols: int) -> None:
    ds.Rows, ds.Columns = rows, cols
    ds.BitsAllocated, ds.BitsStored, ds.HighBit = 16, 16, 15
    ds.PixelRepresentation = 1
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"


def _save(ds, path) -> None:
    if int(pydicom.__version__.split(".")[0]) >= 3:
        ds.save_as(path, enforce_file_format=True)
    else:  # pydicom 2.x
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(path, write_like_original=False)


def _ct_slice(path, raw: np.ndarray, position, orientation, pixel_spacing, slope, intercept,
              series_uid: str) -> None:
    uid = generate_uid()
    ds = FileDataset(str(path), {}, file_meta=_file_meta(CT_IMAGE_STORAGE, uid), preamble=b"\0" * 128)
    ds.SOPClassUID, ds.SOPInstanceUID = CT_IMAGE_STORAGE, uid
    ds.SeriesInstanceUID = series_uid
    ds.Modality = "CT"
    _pixel_module(ds, *raw.shape)
    ds.PixelSpacing = [f"{v:g}" for v in pixel_spacing]
    ds.ImageOrientationPatient = [f"{v:g}" for v in orientation]
    ds.ImagePositionPatient = [f"{v:g}" for v in position]
    ds.RescaleSlope, ds.RescaleIntercept = f"{slope:g}", f"{intercept:g}"
    ds.PixelData = raw.astype("<i2").tobytes()
    _save(ds, path)


ROW_SPACING, COL_SPACING = 0.6, 0.9  # DICOM PixelSpacing = [between rows, between columns]
SLOPE, INTERCEPT = 2.0, -1024.0


def _write_series(folder, orientation, n_slices=5, rows=7, cols=6, gaps=None, seed=0, p0=(-3.0, 4.5, 12.0)):
    """Write a CT series (files in shuffled order); return (raw stack, positions, orientation)."""
    rng = np.random.default_rng(seed)
    row_cos, col_cos = np.array(orientation[:3], float), np.array(orientation[3:], float)
    normal = np.cross(row_cos, col_cos)
    gaps = [1.5] * (n_slices - 1) if gaps is None else gaps
    offsets = np.r_[0.0, np.cumsum(gaps)]
    positions = np.asarray(p0) + offsets[:, None] * normal
    raw = rng.integers(-500, 1500, (n_slices, rows, cols)).astype(np.int16)
    folder.mkdir(exist_ok=True)
    order = list(range(n_slices))
    random.Random(seed).shuffle(order)
    series_uid = generate_uid()
    for name_index, k in enumerate(order):
        _ct_slice(folder / f"IM{name_index:04d}.dcm", raw[k], positions[k], orientation,
                  (ROW_SPACING, COL_SPACING), SLOPE, INTERCEPT, series_uid)
    return raw, positions, row_cos, col_cos


def _expected_points(raw, positions, row_cos, col_cos):
    """World point (LPS) and HU of every pixel, from the DICOM convention alone."""
    k, r, c = np.meshgrid(*[np.arange(n) for n in raw.shape], indexing="ij")
    k, r, c = k.ravel(), r.ravel(), c.ravel()
    world = positions[k] + (c * COL_SPACING)[:, None] * row_cos + (r * ROW_SPACING)[:, None] * col_cos
    return world, raw[k, r, c] * SLOPE + INTERCEPT


@pytest.mark.parametrize(
    "orientation, spacing_xyz",
    [
        # rows along LPS +x, columns along +y, normal -z: slices stacked with descending z
        ((0, 1, 0, 1, 0, 0), (ROW_SPACING, COL_SPACING, 1.5)),
        # coronal, flipped: columns along -x, rows along -z, normal -y
        ((-1, 0, 0, 0, 0, -1), (COL_SPACING, 1.5, ROW_SPACING)),
        # plain axial
        ((1, 0, 0, 0, 1, 0), (COL_SPACING, ROW_SPACING, 1.5)),
    ],
)
def test_dicom_series_geometry_and_hu(tmp_path, orientation, spacing_xyz):
    raw, positions, row_cos, col_cos = _write_series(tmp_path / "series", orientation)
    (tmp_path / "series" / "notes.txt").write_text("not DICOM: skipped")
    vol = load_volume(tmp_path / "series")
    np.testing.assert_allclose(vol.spacing_mm, spacing_xyz, rtol=1e-9)
    world, hu = _expected_points(raw, positions, row_cos, col_cos)
    np.testing.assert_allclose(vol.origin_mm, world.min(axis=0), atol=1e-9)
    np.testing.assert_allclose(vol.sample(world), hu, atol=1e-3)
    # half-way between neighbouring pixels (along the slice normal, then along a row): the mean
    # of their HU values, as trilinear interpolation (§II-A) gives on the right grid only
    rows, cols = raw.shape[1:]
    for a, b in [(1 * rows * cols + 2 * cols + 3, 2 * rows * cols + 2 * cols + 3), (2, 3)]:
        np.testing.assert_allclose(vol.sample((world[a] + world[b]) / 2), (hu[a] + hu[b]) / 2, atol=1e-3)
    assert vol.data.min() >= -500 * SLOPE + INTERCEPT and vol.data.max() < 1500 * SLOPE + INTERCEPT


@pytest.mark.parametrize("tag, victim_name", [("PixelSpacing", "IM0002.dcm"), ("ImagePositionPatient", "IM0001.dcm")])
def test_dicom_missing_geometry_tag_is_named(tmp_path, tag, victim_name):
    _write_series(tmp_path / "s", (1, 0, 0, 0, 1, 0))
    victim = tmp_path / "s" / victim_name
    ds = pydicom.dcmread(victim)
    delattr(ds, tag)
    _save(ds, victim)
    with pytest.raises(ValueError, match=rf"(?s){victim_name.replace('.', chr(92) + '.')}.*without spacing.*{tag}"):
        load_volume(tmp_path / "s")


def test_dicom_non_uniform_duplicate_and_too_few_slices_refused(tmp_path):
    _write_series(tmp_path / "gap", (1, 0, 0, 0, 1, 0), gaps=[1.5, 1.5, 3.0, 1.5])
    with pytest.raises(ValueError, match="not uniformly spaced"):
        load_volume(tmp_path / "gap")
    _write_series(tmp_path / "dup", (1, 0, 0, 0, 1, 0), gaps=[1.5, 0.0, 1.5, 1.5])
    with pytest.raises(ValueError, match="same position"):
        load_volume(tmp_path / "dup")
    _write_series(tmp_path / "one", (1, 0, 0, 0, 1, 0), n_slices=1)
    with pytest.raises(ValueError, match="at least 2"):
        load_volume(tmp_path / "one")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("nothing")
    with pytest.raises(ValueError, match="none of its 1 files"):
        load_volume(tmp_path / "empty")


def test_dicom_oblique_sheared_and_mixed_series_refused(tmp_path):
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    _write_series(tmp_path / "obl", (c, s, 0, -s, c, 0))
    with pytest.raises(ValueError, match=r"(?s)oblique.*resampling is not done"):
        load_volume(tmp_path / "obl")
    # gantry tilt: each slice shifted 1 mm along y within the plane
    _write_series(tmp_path / "tilt", (1, 0, 0, 0, 1, 0))
    for f in sorted((tmp_path / "tilt").iterdir()):
        ds = pydicom.dcmread(f)
        x, y, z = (float(v) for v in ds.ImagePositionPatient)
        ds.ImagePositionPatient = [f"{x:g}", f"{y + (z - 12.0) / 1.5:g}", f"{z:g}"]
        _save(ds, f)
    with pytest.raises(ValueError, match="sheared"):
        load_volume(tmp_path / "tilt")
    # two series in one folder
    _write_series(tmp_path / "mix", (1, 0, 0, 0, 1, 0))
    ds = pydicom.dcmread(tmp_path / "mix" / "IM0000.dcm")
    ds.SeriesInstanceUID = generate_uid()
    _save(ds, tmp_path / "mix" / "IM0000.dcm")
    with pytest.raises(ValueError, match="2 DICOM series"):
        load_volume(tmp_path / "mix")


def _enhanced_ct(path, raw, positions, orientation) -> None:
    from pydicom.dataset import Dataset
    from pydicom.sequence import Sequence

    uid = generate_uid()
    ds = FileDataset(str(path), {}, file_meta=_file_meta(ENHANCED_CT_IMAGE_STORAGE, uid), preamble=b"\0" * 128)
    ds.SOPClassUID, ds.SOPInstanceUID = ENHANCED_CT_IMAGE_STORAGE, uid
    ds.SeriesInstanceUID = generate_uid()
    ds.Modality = "CT"
    _pixel_module(ds, *raw.shape[1:])
    ds.NumberOfFrames = raw.shape[0]
    measures, plane, transform = Dataset(), Dataset(), Dataset()
    measures.PixelSpacing = [f"{ROW_SPACING:g}", f"{COL_SPACING:g}"]
    plane.ImageOrientationPatient = [f"{v:g}" for v in orientation]
    transform.RescaleSlope, transform.RescaleIntercept = f"{SLOPE:g}", f"{INTERCEPT:g}"
    shared = Dataset()
    shared.PixelMeasuresSequence = Sequence([measures])
    shared.PlaneOrientationSequence = Sequence([plane])
    shared.PixelValueTransformationSequence = Sequence([transform])
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    frames = []
    for p in positions:
        pos, item = Dataset(), Dataset()
        pos.ImagePositionPatient = [f"{v:g}" for v in p]
        item.PlanePositionSequence = Sequence([pos])
        frames.append(item)
    ds.PerFrameFunctionalGroupsSequence = Sequence(frames)
    ds.PixelData = raw.astype("<i2").tobytes()
    _save(ds, path)


def test_enhanced_multiframe_dicom(tmp_path):
    orientation = (0, 1, 0, 1, 0, 0)
    rng = np.random.default_rng(5)
    raw = rng.integers(-500, 1500, (4, 7, 6)).astype(np.int16)
    row_cos, col_cos = np.array(orientation[:3], float), np.array(orientation[3:], float)
    positions = np.array([2.0, -1.0, 9.0]) + np.arange(4)[:, None] * 1.5 * np.cross(row_cos, col_cos)
    order = [2, 0, 3, 1]  # frames stored out of order
    _enhanced_ct(tmp_path / "enh.dcm", raw[order], positions[order], orientation)
    vol = load_volume(tmp_path / "enh.dcm")
    np.testing.assert_allclose(vol.spacing_mm, (ROW_SPACING, COL_SPACING, 1.5), rtol=1e-9)
    world, hu = _expected_points(raw, positions, row_cos, col_cos)
    np.testing.assert_allclose(vol.sample(world), hu, atol=1e-3)
    # a single-slice file is not a volume
    _write_series(tmp_path / "single", (1, 0, 0, 0, 1, 0), n_slices=1)
    with pytest.raises(ValueError, match="single slice"):
        load_volume(tmp_path / "single" / "IM0000.dcm")


def test_dicom_series_round_trips_through_nifti(tmp_path):
    raw, positions, row_cos, col_cos = _write_series(tmp_path / "s", (-1, 0, 0, 0, 0, -1))
    vol = load_volume(tmp_path / "s")
    back = load_volume(save_volume_nifti(vol, tmp_path / "s.nii.gz"))
    assert np.array_equal(back.data, vol.data)
    assert np.array_equal(back.spacing_mm, vol.spacing_mm) and np.array_equal(back.origin_mm, vol.origin_mm)


@pytest.mark.filterwarnings("ignore:Invalid value for VR DS:UserWarning")  # pydicom on writing 'nan'/'inf'
@pytest.mark.parametrize("keyword, tag, value", [("RescaleSlope", r"\(0028,1053\)", "nan"),
                                                 ("RescaleIntercept", r"\(0028,1052\)", "-inf")])
def test_dicom_non_finite_rescale_is_refused_at_its_slice(tmp_path, keyword, tag, value):
    _write_series(tmp_path / "s", (1, 0, 0, 0, 1, 0))
    victim = tmp_path / "s" / "IM0003.dcm"
    ds = pydicom.dcmread(victim)
    setattr(ds, keyword, value)
    _save(ds, victim)
    with pytest.raises(ValueError, match=rf"(?s)IM0003\.dcm.*{keyword} {tag} is '{value}', expected a finite number"):
        load_volume(tmp_path / "s")


def test_dicom_non_finite_voxels_are_refused_at_their_slice(tmp_path):
    # a finite slope whose rescale overflows float32 (the Volume's type): every voxel is +-inf
    _write_series(tmp_path / "s", (1, 0, 0, 0, 1, 0))
    victim = tmp_path / "s" / "IM0001.dcm"
    ds = pydicom.dcmread(victim)
    ds.RescaleSlope = "1e38"
    _save(ds, victim)
    with pytest.raises(ValueError, match=r"(?s)IM0001\.dcm.*of 42 voxel values are not finite.*expected finite"):
        load_volume(tmp_path / "s")


@pytest.mark.filterwarnings("ignore::UserWarning")  # pydicom warns about the values it reads cut short
def test_truncated_dicom_slice_is_refused_not_skipped(tmp_path):
    """A slice cut anywhere must not be dropped from the series (an end slice lost would leave a
    uniform, shorter volume) nor escape as pydicom's raw EOFError/struct.error."""
    _write_series(tmp_path / "s", (1, 0, 0, 0, 1, 0))
    victim = tmp_path / "s" / "IM0002.dcm"
    whole = victim.read_bytes()
    for keep in [*range(0, len(whole), 9), len(whole) - 2, len(whole) - 1]:
        victim.write_bytes(whole[:keep])
        with pytest.raises(ValueError, match=r"IM0002\.dcm.*(truncated or corrupt|could not be read)"):
            load_volume(tmp_path / "s")
    victim.write_bytes(whole)
    assert load_volume(tmp_path / "s").data.shape == (5, 7, 6)  # intact again: all five slices


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_truncated_enhanced_multiframe_dicom_is_refused(tmp_path):
    orientation = (1, 0, 0, 0, 1, 0)
    raw = np.random.default_rng(6).integers(-500, 1500, (4, 7, 6)).astype(np.int16)
    positions = np.array([0.0, 0.0, 1.0]) * np.arange(4)[:, None] * 1.5
    _enhanced_ct(tmp_path / "enh.dcm", raw, positions, orientation)
    whole = (tmp_path / "enh.dcm").read_bytes()
    for keep in [100, 300, len(whole) // 2, len(whole) - 50, len(whole) - 1]:
        (tmp_path / "cut.dcm").write_bytes(whole[:keep])
        with pytest.raises(ValueError, match=r"cut\.dcm.*(truncated or corrupt|could not be)"):
            load_volume(tmp_path / "cut.dcm")
    assert load_volume(tmp_path / "enh.dcm").data.shape == (4, 7, 6)
