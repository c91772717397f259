"""histostudy.imaging.io._xa: XA objects written as a C-arm writes them, read back through the
reader of the lab's files (View.from_dicom, load_frame) and pydicom."""

import os

import numpy as np
import pydicom
import pytest

from histostudy.imaging import View, detector_counts, load_frame, write_xa
from histostudy.imaging.io._xa import xa_dataset


@pytest.fixture
def view():
    return View.from_gantry(25.0, -10.0, shape=(48, 62), pixel_mm=2.5, name="A")


def test_a_written_cine_reads_back_with_its_view_and_every_frame(tmp_path, view):
    rng = np.random.default_rng(0)
    L = rng.uniform(0.0, 3.0, size=(3, *view.shape))
    counts = detector_counts(L)
    path = write_xa(tmp_path / "A.dcm", view, counts, frame_time_ms=100.0, uid_seed="run-1")
    again = View.from_dicom(path, name="A")
    points = rng.uniform(-50, 50, (20, 3))
    np.testing.assert_allclose(again.project(points), view.project(points), atol=1e-9)
    for k in range(3):
        frame = load_frame(path, again, frame_index=k, line_integrals=False, air_value=4095.0)
        # -log(I/I0) of the rounded counts: within the 12-bit quantisation of the line integrals
        np.testing.assert_allclose(frame.image, -np.log(np.maximum(counts[k], 1) / 4095.0), atol=1e-9)
        assert np.max(np.abs(frame.image - L[k])) < 0.5 * np.exp(3.0) / 4095 + 1e-9
    ds = pydicom.dcmread(path)
    assert (ds.SOPClassUID, ds.Modality, ds.SeriesDescription, int(ds.NumberOfFrames)) == \
        ("1.2.840.10008.5.1.4.1.1.12.1", "XA", "A", 3)
    assert float(ds.FrameTime) == 100.0
    assert oct(os.stat(path).st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_the_same_seed_writes_the_same_bytes_and_planes_share_a_study(tmp_path, view):
    counts = detector_counts(np.zeros((2, *view.shape)))
    a = write_xa(tmp_path / "a.dcm", view, counts, uid_seed="s").read_bytes()
    b = write_xa(tmp_path / "b.dcm", view, counts, uid_seed="s").read_bytes()
    assert a == b
    other = View.from_gantry(-60.0, 0.0, shape=view.shape, pixel_mm=2.5, name="B")
    ds_a, ds_b = xa_dataset(view, counts, uid_seed="s"), xa_dataset(other, counts, uid_seed="s")
    assert ds_a.StudyInstanceUID == ds_b.StudyInstanceUID
    assert ds_a.SeriesInstanceUID != ds_b.SeriesInstanceUID and ds_a.SOPInstanceUID != ds_b.SOPInstanceUID


def test_bad_input_is_refused_by_name(tmp_path, view):
    counts = detector_counts(np.zeros(view.shape))
    with pytest.raises(ValueError, match="carries no gantry"):
        xa_dataset(View.from_matrix(view.P, view.shape, view.pixel_mm), counts)
    with pytest.raises(ValueError, match=r"intensities must be .* shape \(48, 62\)"):
        xa_dataset(view, np.zeros((10, 10), np.uint16))
    with pytest.raises(ValueError, match="integer counts in 0..4095"):
        xa_dataset(view, np.full(view.shape, 5000, np.uint16))
    with pytest.raises(ValueError, match="bits_stored"):
        xa_dataset(view, counts, bits_stored=20)
    with pytest.raises(ValueError, match="line_integrals must be finite"):
        detector_counts(np.full(view.shape, np.nan))
    with pytest.raises(ValueError, match="i0"):
        detector_counts(np.zeros(view.shape), i0=1e6)
    assert not list(tmp_path.iterdir())  # nothing half-written


@pytest.mark.parametrize("rows, cols, frames, kept", [(48, 64, 1, "read"), (40, 64, 1, "long"), (48, 64, 2, "short"),
                                                      (48, 60, 1, "long")])
def test_rows_or_columns_that_disagree_with_the_pixel_data_are_refused_as_corrupt(tmp_path, view, rows, cols, frames,
                                                                                  kept):
    """An object whose Rows / Columns / NumberOfFrames ask for more bytes than PixelData holds, or
    fewer (pydicom only warned, and the frame was posed on shifted rows until the verdict refused
    it), is refused before its pixels are read, by every reader."""
    from histostudy.imaging.io import XRayObjectRejected, check_xray_object

    small = View.from_gantry(0.0, 0.0, shape=(48, 64), pixel_mm=0.6, name="A")
    path = write_xa(tmp_path / "A.dcm", small, np.full((48, 64), 1000, np.uint16))
    ds = pydicom.dcmread(path)
    ds.Rows, ds.Columns = rows, cols
    if frames > 1:
        ds.NumberOfFrames = frames
    ds.save_as(path)
    if kept == "read":  # the object as written
        check_xray_object(pydicom.dcmread(path))
        return
    match = {"short": r"cannot be read: PixelData holds 6144 bytes, its \d frame\(s\) of \d+ x \d+ need \d+",
             "long": r"is corrupt: PixelData holds 6144 bytes, more than its 1 frame\(s\) of \d+ x \d+ "
                     r"\(Rows, Columns, NumberOfFrames\) take, \d+"}[kept]
    for read in (lambda: check_xray_object(pydicom.dcmread(path)), lambda: load_frame(path, small, resample=True)):
        with pytest.raises(XRayObjectRejected, match=match) as refused:
            read()
        assert refused.value.status == 0xA900
