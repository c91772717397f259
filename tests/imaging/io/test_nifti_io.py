"""NIfTI CBCT volumes (histostudy.imaging.io._nifti, read through load_volume): exact round trips,
reorientation of permuted and flipped affines, scaling and units, refused geometries.

Every geometry test checks values at world points against a ground truth computed independently
from the file's own convention (NIfTI affine -> RAS -> LPS), so a swapped axis, a lost flip or a
half-voxel shift fails, not only a wrong shape.
"""

import nibabel as nib
import numpy as np
import pytest

from histostudy.imaging import Volume, load_volume, save_volume_nifti

RAS_TO_LPS = np.array([-1.0, -1.0, 1.0])


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
@pytest.mark.parametrize(
    "spacing, origin, header_class",
    [
        # float32-exact geometry -> NIfTI-1; geometry float32 cannot hold -> NIfTI-2 (float64).
        ((0.5, 0.75, 1.25), (-10.5, 20.25, 3.0), nib.Nifti1Header),
        ((0.7, 0.55, 1.3), (-12.3, 45.6, 7.89), nib.Nifti2Header),
    ],
)
def test_nifti_round_trip_is_exact(tmp_path, suffix, spacing, origin, header_class):
    rng = np.random.default_rng(1)
    vol = Volume(rng.normal(0, 300, (8, 7, 6)).astype(np.float32), spacing, origin)
    path = save_volume_nifti(vol, tmp_path / f"cbct{suffix}")
    assert path.exists() and [p.name for p in tmp_path.iterdir()] == [f"cbct{suffix}"]  # no temp file left
    assert type(nib.load(str(path)).header) is header_class
    back = load_volume(path)
    assert back.data.dtype == np.float32 and back.data.shape == vol.data.shape
    assert np.array_equal(back.data, vol.data)
    assert np.array_equal(back.spacing_mm, vol.spacing_mm)
    assert np.array_equal(back.origin_mm, vol.origin_mm)
    pts = vol.origin_mm + rng.uniform(0, 1, (20, 3)) * (vol.upper_mm - vol.origin_mm)
    assert np.array_equal(back.sample(pts), vol.sample(pts))


def test_nifti_permuted_flipped_affine_samples_the_right_voxels(tmp_path):
    rng = np.random.default_rng(2)
    data = rng.normal(0, 100, (6, 7, 8)).astype(np.float32)  # nibabel order (i, j, k)
    # i -> RAS +y (0.7 mm), j -> RAS -z (1.2 mm), k -> RAS -x (0.5 mm): a permutation with flips.
    affine = np.array([
        [0.0, 0.0, -0.5, 10.0],
        [0.7, 0.0, 0.0, -20.0],
        [0.0, -1.2, 0.0, 30.0],
        [0.0, 0.0, 0.0, 1.0],
    ])
    nib.save(nib.Nifti1Image(data, affine), tmp_path / "perm.nii.gz")
    vol = load_volume(tmp_path / "perm.nii.gz")
    # ground truth from the affine as stored (float32 in NIfTI-1: 0.7 is 0.69999999)
    affine = nib.load(tmp_path / "perm.nii.gz").affine
    np.testing.assert_allclose(vol.spacing_mm, [0.5, 0.7, 1.2], rtol=1e-6)  # LPS x <- k, y <- i, z <- j
    assert vol.shape_xyz == (8, 6, 7)
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in data.shape], indexing="ij"), -1).reshape(-1, 3)
    lps = (np.c_[ijk, np.ones(len(ijk))] @ affine.T)[:, :3] * RAS_TO_LPS
    np.testing.assert_allclose(vol.sample(lps), data[tuple(ijk.T)], rtol=1e-5, atol=1e-4)
    assert np.all(vol.spacing_mm > 0)
    # the first voxel centre is the LPS-lowest corner of the grid
    np.testing.assert_allclose(vol.origin_mm, lps.min(axis=0), atol=1e-5)


def _patch_nifti_header(path, **fields):
    """Set raw header fields of an uncompressed .nii in place (nibabel recomputes them on save)."""
    with open(path, "rb+") as fh:
        hdr = nib.Nifti1Header.from_fileobj(fh)
        for key, value in fields.items():
            hdr[key] = value
        fh.seek(0)
        hdr.write_to(fh)


def test_nifti_scaling_and_units_are_applied(tmp_path):
    raw = np.arange(6 * 7 * 8, dtype=np.int16).reshape(6, 7, 8)
    img = nib.Nifti1Image(raw, np.diag([1.0, 1.0, 1.0, 1.0]))
    img.set_data_dtype(np.int16)
    nib.save(img, tmp_path / "s.nii")
    _patch_nifti_header(tmp_path / "s.nii", scl_slope=2.0, scl_inter=-1000.0)
    vol = load_volume(tmp_path / "s.nii")
    # identity RAS affine: LPS x and y run backwards, so the volume is flipped there
    expected = (raw.astype(np.float64) * 2 - 1000)[::-1, ::-1, :].transpose(2, 1, 0)
    assert np.array_equal(vol.data, expected.astype(np.float32))
    # the same grid in metres: 1 unit = 1000 mm
    _patch_nifti_header(tmp_path / "s.nii", xyzt_units=1)  # NIFTI_UNITS_METER
    assert np.array_equal(load_volume(tmp_path / "s.nii").spacing_mm, [1000.0] * 3)


def test_nifti_4d_with_one_volume_is_squeezed_others_refused(tmp_path):
    data = np.random.default_rng(3).normal(size=(6, 7, 8, 1)).astype(np.float32)
    nib.save(nib.Nifti1Image(data, np.diag([-0.5, -0.5, 0.5, 1.0])), tmp_path / "a.nii")
    vol = load_volume(tmp_path / "a.nii")
    assert np.array_equal(vol.data, data[..., 0].transpose(2, 1, 0))
    nib.save(nib.Nifti1Image(np.zeros((6, 7, 8, 2), np.float32), np.eye(4)), tmp_path / "b.nii")
    with pytest.raises(ValueError, match="3-D volume"):
        load_volume(tmp_path / "b.nii")


def test_nifti_oblique_and_spacingless_are_refused(tmp_path):
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    oblique = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    nib.save(nib.Nifti1Image(np.zeros((6, 7, 8), np.float32), oblique), tmp_path / "obl.nii")
    with pytest.raises(ValueError, match=r"(?s)oblique.*direction cosines.*resampling is not done") as err:
        load_volume(tmp_path / "obl.nii")
    assert "obl.nii" in str(err.value)
    # nibabel will not write a zero voxel size itself: patch a valid file's header
    good = nib.Nifti1Image(np.zeros((6, 7, 8), np.float32), np.diag([0.5, 0.7, 1.2, 1.0]))
    nib.save(good, tmp_path / "z.nii")
    _patch_nifti_header(tmp_path / "z.nii", pixdim=[1.0, 0.5, 0.0, 1.2, 1.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"(?s)z\.nii.*without spacing.*pixdim.*0\.0"):
        load_volume(tmp_path / "z.nii")
    nib.save(good, tmp_path / "s.nii")
    _patch_nifti_header(tmp_path / "s.nii", srow_y=[0.0, 0.0, 0.0, 0.0])  # sform with a zero axis
    with pytest.raises(ValueError, match=r"(?s)s\.nii.*without spacing.*step lengths"):
        load_volume(tmp_path / "s.nii")


def test_nifti_without_qform_or_sform_warns(tmp_path):
    img = nib.Nifti1Image(np.zeros((6, 7, 8), np.float32), np.eye(4))
    img.set_sform(None, code=0)
    img.set_qform(None, code=0)
    nib.save(img, tmp_path / "n.nii")
    with pytest.warns(UserWarning, match="position in the C-arm frame is unknown"):
        load_volume(tmp_path / "n.nii")


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
def test_truncated_nifti_is_refused_naming_the_file(tmp_path, suffix):
    """A file cut anywhere (in the header, the voxels, or only the gzip trailer) is a ValueError
    naming the file, never nibabel's OSError or gzip's EOFError escaping raw."""
    vol = Volume(np.random.default_rng(4).normal(0, 300, (20, 15, 10)).astype(np.float32), 0.5)
    whole = save_volume_nifti(vol, tmp_path / f"whole{suffix}").read_bytes()
    for keep in [10, 200, 400, len(whole) // 2, len(whole) - 9, len(whole) - 4, len(whole) - 1]:
        cut = tmp_path / f"cut{keep}{suffix}"
        cut.write_bytes(whole[:keep])
        with pytest.raises(ValueError, match=rf"cut{keep}\.nii.*(truncated or corrupt|could not be read)") as err:
            load_volume(cut)
        assert err.value.__cause__ is not None  # the reader's own error stays on the chain
    # the voxels or the gzip trailer cut: the reader's error is chained, the message says truncated
    cut = tmp_path / f"half{suffix}"
    cut.write_bytes(whole[: len(whole) - 100])
    with pytest.raises(ValueError, match=r"half\.nii.*is truncated or corrupt") as err:
        load_volume(cut)
    assert isinstance(err.value.__cause__, (OSError, EOFError))
    assert np.array_equal(load_volume(tmp_path / f"whole{suffix}").data, vol.data)  # the intact file still reads
