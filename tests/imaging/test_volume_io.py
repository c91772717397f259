"""histostudy.imaging.volume_io: which reader a path goes to, and what is refused before reading."""

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
