"""Frames: validation, and loading real frames from .npy / .png / DICOM."""

import cv2
import numpy as np
import pytest

from histostudy.imaging import Frame, View, line_integrals_from_pixels, load_frame


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
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.12.1"  # X-Ray Angiographic Image Storage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    ds = FileDataset(str(tmp_path / "f.dcm"), {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID = meta.MediaStorageSOPClassUID
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
    with pytest.raises(ValueError, match=r"holds a \(5, 5\) image, the view '' expects \(12, 16\).*resample=True"):
        load_frame(tmp_path / "small.npy", view)
    (tmp_path / "x.bmpx").write_bytes(b"")
    with pytest.raises(ValueError, match="unknown image format"):
        load_frame(tmp_path / "x.bmpx", view)


def test_frame_labels_outside_the_feature_values_are_refused_not_wrapped():
    view = View.from_gantry(0.0, 0.0, shape=(12, 16), name="A")
    with pytest.raises(ValueError, match=r"labels must hold Feature values 0..5 \(integers\), got \[300\]"):
        Frame(np.zeros((12, 16)), view, labels=np.full((12, 16), 300))


def _xa_cine(path, frames, photometric="MONOCHROME2", slope=None, bits=12):
    """A multi-frame XA object (what a C-arm exports) holding ``frames`` (n, rows, cols) uint16."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian

    ds = Dataset()
    ds.file_meta = FileMetaDataset()
    ds.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds.SOPClassUID, ds.SOPInstanceUID = "1.2.840.10008.5.1.4.1.1.12.1", "1.2.3.4.5"
    ds.file_meta.MediaStorageSOPClassUID, ds.file_meta.MediaStorageSOPInstanceUID = ds.SOPClassUID, ds.SOPInstanceUID
    ds.Modality = "XA"
    ds.NumberOfFrames, (ds.Rows, ds.Columns) = len(frames), frames.shape[1:]
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, photometric
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, bits, bits - 1, 0
    if slope is not None:
        ds.RescaleSlope, ds.RescaleIntercept = slope, 0.0
    ds.PixelData = frames.astype(np.uint16).tobytes()
    ds.save_as(path, enforce_file_format=True)
    return path


def test_a_frame_of_an_xa_cine_is_loaded_by_its_index(tmp_path, view):
    rng = np.random.default_rng(2)
    frames = rng.integers(100, 4000, size=(3, 12, 16))
    path = _xa_cine(tmp_path / "cine.dcm", frames)
    second = load_frame(path, view, frame_index=1)
    np.testing.assert_array_equal(second.image, frames[1].astype(np.float32))
    assert second.meta["frame_index"] == 1
    with pytest.raises(ValueError, match="holds 3 frames: pass frame_index"):
        load_frame(path, view)
    with pytest.raises(ValueError, match=r"frame_index must be in \[0, 3\)"):
        load_frame(path, view, frame_index=3)
    intensity = load_frame(path, view, frame_index=2, line_integrals=False, air_value=4095.0)
    np.testing.assert_allclose(intensity.image, -np.log(frames[2] / 4095.0), rtol=1e-5)


def test_monochrome1_is_inverted_and_a_bad_rescale_refused(tmp_path, view):
    frames = np.random.default_rng(3).integers(0, 4096, size=(2, 12, 16))
    mono1 = load_frame(_xa_cine(tmp_path / "m1.dcm", frames, "MONOCHROME1", slope=2.0), view, frame_index=0)
    np.testing.assert_array_equal(mono1.image, (2.0 * (4095 - frames[0])).astype(np.float32))
    with pytest.raises(ValueError, match=r"RescaleSlope \(0028,1053\) must be a finite number"):
        load_frame(_xa_cine(tmp_path / "nan.dcm", frames, slope="NaN"), view, frame_index=0)


def test_a_frame_of_another_size_is_resampled_onto_the_view_when_asked(tmp_path, view):
    big = np.kron(np.arange(12 * 16, dtype=float).reshape(12, 16), np.ones((2, 2)))  # each pixel as 2x2
    np.save(tmp_path / "big.npy", big)
    frame = load_frame(tmp_path / "big.npy", view, resample=True)
    np.testing.assert_allclose(frame.image, np.arange(12 * 16).reshape(12, 16))  # area means give the pixels back


def test_line_integrals_from_pixels_reads_the_pixel_module_and_refuses_what_it_cannot_use():
    from types import SimpleNamespace

    counts = np.random.default_rng(4).integers(1, 4096, size=(2, 12, 16))
    mono2 = SimpleNamespace(PhotometricInterpretation="MONOCHROME2", BitsStored=12, RescaleSlope="2.0",
                            RescaleIntercept="0")
    mono1 = SimpleNamespace(**{**vars(mono2), "PhotometricInterpretation": "MONOCHROME1"})
    L = line_integrals_from_pixels(counts, mono2)
    # the same intensities stored inverted (MONOCHROME1: low values white) give the same line integrals
    np.testing.assert_array_equal(line_integrals_from_pixels(4095 - counts, mono1), L)
    # -log(I / I0), I0 each frame's maximum (so the slope cancels): 0 at each frame's brightest pixel
    assert L.dtype == np.float32 and L.shape == counts.shape
    for frame, c in zip(L, counts):
        np.testing.assert_allclose(frame, -np.log(c / c.max()), rtol=1e-6)
    # a fixed air value I0 (modality units); the rescale intercept shifts I before the log
    np.testing.assert_allclose(line_integrals_from_pixels(counts[0], air_value=4095.0), -np.log(counts[0] / 4095),
                               rtol=1e-6)
    shifted = SimpleNamespace(RescaleIntercept=100.0)
    np.testing.assert_allclose(line_integrals_from_pixels(counts[0], shifted, air_value=4195.0),
                               -np.log((counts[0] + 100.0) / 4195.0), rtol=1e-6)
    with pytest.raises(ValueError, match=r"^path 'x.dcm': RescaleSlope \(0028,1053\) must be a finite number, "
                                         r"got nan"):
        line_integrals_from_pixels(counts, SimpleNamespace(RescaleSlope=float("nan")), source="path 'x.dcm'")
    with pytest.raises(ValueError, match=r"RescaleIntercept \(0028,1052\) must be a finite number, got 'inf'"):
        line_integrals_from_pixels(counts, SimpleNamespace(RescaleIntercept="inf"))
    with pytest.raises(ValueError, match=r"BitsStored \(0028,0101\) must be an integer in 1..32, got 40"):
        line_integrals_from_pixels(counts, SimpleNamespace(PhotometricInterpretation="MONOCHROME1", BitsStored=40))
    with pytest.raises(ValueError, match=r"frame 1 holds no X-ray signal \(I0 = its maximum = 0.0\)"):
        line_integrals_from_pixels(np.stack([counts[0], np.zeros((12, 16))]))
    with pytest.raises(ValueError, match=r"air_value must be None or a finite intensity > 0, got -1.0"):
        line_integrals_from_pixels(counts, air_value=-1.0)
    with pytest.raises(ValueError, match=r"pixels must be a real \(rows, cols\) or \(frames, rows, cols\) array"):
        line_integrals_from_pixels(np.zeros(5))
