"""histostudy.imaging.io._volumes: which reader a path goes to, and what is refused before reading."""

import numpy as np
import pytest

from histostudy.imaging import Volume, load_volume, save_volume_nifti


def test_unsupported_and_missing_paths(tmp_path):
    (tmp_path / "vol.mha").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"(?s)vol\.mha.*unsupported.*\.nii\.gz"):
        load_volume(tmp_path / "vol.mha")
    with pytest.raises(FileNotFoundError, match="missing.nii"):
        load_volume(tmp_path / "missing.nii")
    vol = Volume(np.zeros((2, 2, 2)), 1.0)
    with pytest.raises(ValueError, match=r"\.nii"):
        save_volume_nifti(vol, tmp_path / "out.mha")
    with pytest.raises(TypeError, match="Volume"):
        save_volume_nifti(np.zeros((2, 2, 2)), tmp_path / "out.nii")


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the overflow under test
def test_non_finite_voxels_are_refused_naming_the_file_and_count(tmp_path):
    """NaN/inf voxels would pass silently through every trilinear sample and threshold."""
    import nibabel as nib

    data = np.zeros((6, 7, 8), np.float32)
    data[1, 2, 3], data[4, 5, 6], data[0, 0, 0] = np.nan, np.inf, -np.inf
    nib.save(nib.Nifti1Image(data, np.diag([-0.5, -0.5, 0.5, 1.0])), tmp_path / "nan.nii")
    with pytest.raises(ValueError, match=r"(?s)nan\.nii.*3 of 336 voxel values are not finite \(1 NaN, 2 infinite\)"
                                         r".*expected finite values"):
        load_volume(tmp_path / "nan.nii")
    # a header scaling that overflows float32 (int16 * 1e38) is refused the same way
    raw = nib.Nifti1Image(np.full((6, 7, 8), 1000, np.int16), np.eye(4))
    raw.set_data_dtype(np.int16)
    raw.header.set_slope_inter(1e38, 0.0)
    nib.save(raw, tmp_path / "big.nii")
    with pytest.raises(ValueError, match=r"(?s)big\.nii.*336 of 336 voxel values are not finite"):
        load_volume(tmp_path / "big.nii")
