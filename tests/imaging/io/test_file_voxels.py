"""A voxel as the user reads it off a viewer (Volume.file_voxel_to_world, §II-D): the file's own
indexing — nibabel's (i, j, k) of a NIfTI array, (column, row, slice) of a DICOM series — whatever
way load_volume reorients the grid. Each world point is checked against an independent reference:
nibabel's affine (RAS, so x and y negated to LPS) or the DICOM standard's position + index *
spacing * cosine, and against the value the file stores at that voxel."""

import nibabel as nib
import numpy as np
import pydicom
import pytest
from nibabel.affines import apply_affine
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian, generate_uid

from histostudy.imaging import Volume, load_volume, lps_from_ras, ras_from_lps, save_volume_nifti
from histostudy.imaging.volume import LPS_FROM_RAS

SHAPE_IJK = (5, 6, 7)
# RAS-increasing (as FSL and many converters write), and a permuted, flipped grid.
AFFINES = {
    "ras": np.array([[0.7, 0, 0, -10.0], [0, 0.8, 0, 4.0], [0, 0, 0.9, 2.5], [0, 0, 0, 1]]),
    "permuted": np.array([[0, -0.8, 0, 6.0], [0, 0, 0.9, -3.0], [-0.7, 0, 0, 1.5], [0, 0, 0, 1]]),
}


@pytest.mark.parametrize("name", sorted(AFFINES))
def test_a_nifti_voxel_is_where_nibabels_affine_puts_it(tmp_path, name):
    affine = AFFINES[name]
    values = np.random.default_rng(0).normal(size=SHAPE_IJK).astype(np.float32)
    img = nib.Nifti1Image(values, affine)
    img.header.set_xyzt_units(xyz="mm")
    nib.save(img, tmp_path / "v.nii.gz")
    volume = load_volume(tmp_path / "v.nii.gz")
    ijk = np.array([[0, 0, 0], [4, 5, 6], [1, 3, 2], [3, 0, 5]])
    world = volume.file_voxel_to_world(ijk)
    np.testing.assert_allclose(world, apply_affine(affine, ijk) @ LPS_FROM_RAS.T, atol=1e-5)
    # and the volume holds, there, the value the file stores at that voxel
    np.testing.assert_allclose(volume.sample(world), values[tuple(ijk.T)], atol=1e-5)
    # the reoriented grid's own indices differ for these files: the bug the file indexing fixes
    assert not np.allclose(volume.voxel_to_world(ijk), world)


def test_the_nifti_we_write_indexes_as_its_volume(tmp_path):
    volume = Volume(np.zeros((4, 3, 2)), (0.5, 0.6, 0.7), (-1.0, 2.0, 3.0))
    save_volume_nifti(volume, tmp_path / "v.nii")
    img = nib.load(tmp_path / "v.nii")
    read = load_volume(tmp_path / "v.nii")
    ijk = np.array([[1, 2, 3], [0, 0, 0]])
    np.testing.assert_allclose(read.file_voxel_to_world(ijk), apply_affine(img.affine, ijk) @ LPS_FROM_RAS.T)
    np.testing.assert_allclose(read.file_voxel_to_world(ijk), volume.voxel_to_world(ijk))
    np.testing.assert_allclose(volume.file_voxel_to_world(ijk), volume.voxel_to_world(ijk))


def _write_series(folder, raw, row_cos, col_cos, spacing_rc, p0, gap):
    normal = np.cross(row_cos, col_cos)
    positions = []
    series = generate_uid()
    for s, pixels in enumerate(raw):
        position = np.asarray(p0) + s * gap * normal
        positions.append(position)
        uid = generate_uid()
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID, meta.MediaStorageSOPInstanceUID = "1.2.840.10008.5.1.4.1.1.2", uid
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = FileDataset(str(folder / f"{s}.dcm"), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.SOPClassUID, ds.SOPInstanceUID, ds.SeriesInstanceUID, ds.Modality = meta.MediaStorageSOPClassUID, uid, \
            series, "CT"
        ds.Rows, ds.Columns = pixels.shape
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.PixelSpacing = [f"{v:g}" for v in spacing_rc]
        ds.ImageOrientationPatient = [f"{v:g}" for v in (*row_cos, *col_cos)]
        ds.ImagePositionPatient = [f"{v:g}" for v in position]
        ds.PixelData = pixels.astype("<i2").tobytes()
        if int(pydicom.__version__.split(".")[0]) >= 3:
            ds.save_as(folder / f"{s}.dcm", enforce_file_format=True)
        else:
            ds.is_little_endian, ds.is_implicit_VR = True, False
            ds.save_as(folder / f"{s}.dcm", write_like_original=False)
    return np.array(positions)


def test_a_dicom_voxel_is_column_row_slice_by_the_standards_geometry(tmp_path):
    # rows run towards the patient's right (-x) and columns posterior (+y): the volume is flipped in x
    row_cos, col_cos = np.array([-1.0, 0, 0]), np.array([0, 1.0, 0])
    spacing_rc = (0.6, 0.9)  # between rows, between columns
    raw = np.random.default_rng(1).integers(-500, 1500, (4, 5, 6)).astype(np.int16)  # [slice, row, column]
    positions = _write_series(tmp_path, raw, row_cos, col_cos, spacing_rc, (3.0, -2.0, 10.0), 1.5)
    volume = load_volume(tmp_path)
    crs = np.array([[0, 0, 0], [5, 4, 3], [2, 1, 3], [4, 3, 1]])  # (column, row, slice)
    c, r, s = crs.T
    expected = positions[s] + (c * spacing_rc[1])[:, None] * row_cos + (r * spacing_rc[0])[:, None] * col_cos
    world = volume.file_voxel_to_world(crs)
    np.testing.assert_allclose(world, expected, atol=1e-6)
    np.testing.assert_allclose(volume.sample(world), raw[s, r, c], atol=1e-3)


def test_ras_and_lps_are_each_others_mirror_in_x_and_y():
    lps = np.array([[1.0, -2.0, 3.0], [0.5, 0.25, -7.0]])
    np.testing.assert_allclose(ras_from_lps(lps), lps * [-1, -1, 1])
    np.testing.assert_allclose(lps_from_ras(ras_from_lps(lps)), lps)
    with pytest.raises(ValueError, match="points_ras_mm"):
        lps_from_ras([1.0, 2.0])


def test_a_bad_file_voxel_affine_is_refused():
    with pytest.raises(ValueError, match="T_world_file_voxel"):
        Volume(np.zeros((2, 2, 2)), 1.0, 0.0, np.zeros((4, 4)))
