"""A frame file that cannot be read is named in every reader's error, with what is wrong: missing, a
folder, not DICOM, cut short anywhere (read_dicom_file, and through it View.from_dicom and
load_frame, the readers of ``histostudy pose`` and ``calibrate``); the exception stays a
ValueError or an OSError, as callers catch it."""

import numpy as np
import pytest

from histostudy.imaging import View, default_biplane, load_frame, write_xa
from histostudy.imaging.io import read_dicom_file

SHAPE = (48, 62)


@pytest.fixture(scope="module")
def xa(tmp_path_factory):
    view = default_biplane(shape=SHAPE, pixel_mm=6.16)[0]
    path = write_xa(tmp_path_factory.mktemp("xa") / "A.dcm", view, np.full(SHAPE, 1000, np.uint16))
    return path, view


def _readers(path, view):
    return {"read_dicom_file": lambda: read_dicom_file(path),
            "View.from_dicom": lambda: View.from_dicom(path),
            "load_frame": lambda: load_frame(path, view, line_integrals=False)}


@pytest.mark.parametrize("keep, why", [(0, "does not start as a DICOM file does"),
                                       (100, "does not start as a DICOM file does"),
                                       (300, "no data set follows its file meta information"),
                                       (700, "its last data element .* ends at byte")])
def test_a_file_cut_in_its_header_is_named_by_every_reader(xa, tmp_path, keep, why):
    path, view = xa
    cut = tmp_path / "cut.dcm"
    cut.write_bytes(path.read_bytes()[:keep])
    for name, read in _readers(cut, view).items():
        with pytest.raises(ValueError, match=rf"DICOM file '{cut}'.*{why}") as refused:
            read()
        assert "force=True" not in str(refused.value), name  # pydicom's advice names a Python argument


def test_a_file_cut_in_its_pixels_is_named_where_they_are_read(xa, tmp_path):
    path, view = xa
    cut = tmp_path / "cut.dcm"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) - 100])
    assert View.from_dicom(cut).shape == SHAPE  # the header is whole
    for read in (lambda: read_dicom_file(cut), lambda: load_frame(cut, view, line_integrals=False)):
        with pytest.raises(ValueError, match=rf"DICOM file '{cut}' is truncated or corrupt: its last data element "
                                             r"\(7FE0,0010\)"):
            read()


def test_missing_files_folders_and_other_files_are_named(xa, tmp_path):
    path, view = xa
    with pytest.raises(FileNotFoundError, match=rf"DICOM file '{tmp_path / 'none.dcm'}': no such file"):
        View.from_dicom(tmp_path / "none.dcm")
    with pytest.raises(IsADirectoryError, match=rf"DICOM file '{tmp_path}' is a folder"):
        read_dicom_file(tmp_path)
    (tmp_path / "notes").write_text("not an image")  # no suffix: read as DICOM, as the frame readers do
    with pytest.raises(ValueError, match=rf"'{tmp_path / 'notes'}' could not be read as DICOM.*not a DICOM file"):
        load_frame(tmp_path / "notes", view)
    assert read_dicom_file(path).Rows == SHAPE[0] and "PixelData" not in read_dicom_file(path, stop_before_pixels=True)
