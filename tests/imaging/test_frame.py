"""Frames: validation, and loading real frames from .npy / .png / DICOM."""

import cv2
import numpy as np
import pytest

from histostudy.imaging import Frame, View, load_frame


@pytest.fixture
def view():
    return View.from_gantry(0, 0, shape=(12, 16), pixel_mm=2.0)


def test_frame_validates_shapes_and_pose(view):
    img = np.ones((12, 16))
    f = Frame(img, view, labels=np.zeros((12, 16), int), T_carm_transducer=np.eye(4))
    assert f.image.dtype == np.float32 and f.labels.dtype == np.uint8 and f.shape == (12, 16)
    with pytest.raises(ValueError, match="does not match view"):
        Frame(np.ones((10, 16)), view)
    with pytest.raises(ValueError, match=r"labels must be shape \(12, 16\)"):
        Frame(img, view, labels=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="T_carm_transducer"):
        Frame(img, view, T_carm_transducer=np.diag([1, 1, 2, 1.0]))
    with pytest.raises(ValueError, match="finite"):
        Frame(np.full((12, 16), np.nan), view)
    with pytest.raises(TypeError, match="View"):
        Frame(img, "A")


def test_load_npy_and_png(tmp_path, view):
    data = np.random.default_rng(0).uniform(0, 5, (12, 16)).astype(np.float32)
    np.save(tmp_path / "f.npy", data)
    f = load_frame(tmp_path / "f.npy", view)
    assert np.array_equal(f.image, data) and f.labels is None and f.T_carm_transducer is None
    raw = np.full((12, 16), 40000, np.uint16)
    raw[3, 4] = 4000
    cv2.imwrite(str(tmp_path / "raw.png"), raw)
    g = load_frame(tmp_path / "raw.png", view, line_integrals=False)
    assert g.image[0, 0] == pytest.approx(0.0) and g.image[3, 4] == pytest.approx(np.log(10), rel=1e-5)


def test_load_dicom(tmp_path, view):
    pytest.importorskip("pydicom")
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    meta = FileMetaDataset()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    meta.MediaStorageSOPClassUID = generate_uid()
    meta.MediaStorageSOPInstanceUID = generate_uid()
    ds = FileDataset(str(tmp_path / "f.dcm"), {}, file_meta=meta, preamble=b"\0" * 128)
    pixels = (np.arange(12 * 16) % 100).reshape(12, 16).astype(np.uint16)
    ds.Rows, ds.Columns = pixels.shape
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.RescaleSlope, ds.RescaleIntercept = 0.01, 0.0
    ds.PixelData = pixels.tobytes()
    ds.save_as(tmp_path / "f.dcm", enforce_file_format=True)
    f = load_frame(tmp_path / "f.dcm", view)
    assert np.allclose(f.image, pixels * 0.01, atol=1e-6)


def test_load_rejects_wrong_shape_and_unknown_format(tmp_path, view):
    np.save(tmp_path / "small.npy", np.zeros((5, 5)))
    with pytest.raises(ValueError, match="does not match view"):
        load_frame(tmp_path / "small.npy", view)
    (tmp_path / "x.bmpx").write_bytes(b"")
    with pytest.raises(ValueError, match="unknown image format"):
        load_frame(tmp_path / "x.bmpx", view)


def test_frame_labels_outside_the_feature_values_are_refused_not_wrapped():
    view = View.from_gantry(0.0, 0.0, shape=(12, 16), name="A")
    with pytest.raises(ValueError, match=r"labels must hold Feature values 0..5 \(integers\), got \[300\]"):
        Frame(np.zeros((12, 16)), view, labels=np.full((12, 16), 300))
