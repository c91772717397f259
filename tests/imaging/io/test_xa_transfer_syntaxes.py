"""The transfer syntaxes the readers of XA frames decode (histostudy.imaging.RECEIVABLE_TRANSFER_SYNTAXES):
a two-frame 12-bit cine written uncompressed, rewritten in each syntax by DCMTK (else pydicom's or
Pillow's encoder, else skipped: xa_codecs), and read back bit for bit by load_frame (histostudy pose,
calibrate) and by the live receiver's decoding (decode_xray_object); lossy pixels (near-lossless
JPEG-LS, irreversible JPEG 2000, lossy JPEG) and unknown syntaxes refused by name."""

import numpy as np
import pydicom
import pytest
from pydicom.pixels import get_decoder
from xa_codecs import NEAR, compress, jpeg_ls_near

from histostudy.imaging import View, detector_counts, load_frame, write_xa
from histostudy.imaging.io import RECEIVABLE_TRANSFER_SYNTAXES, XRayObjectRejected, check_xray_object, xray_pixels
from histostudy.lab.xray_objects import decode_xray_object

NATIVE = ["1.2.840.10008.1.2", "1.2.840.10008.1.2.1", "1.2.840.10008.1.2.1.99", "1.2.840.10008.1.2.2"]
COMPRESSED = ["1.2.840.10008.1.2.4.70", "1.2.840.10008.1.2.4.57", "1.2.840.10008.1.2.4.80", "1.2.840.10008.1.2.4.81",
              "1.2.840.10008.1.2.4.90", "1.2.840.10008.1.2.4.91", "1.2.840.10008.1.2.5"]
#: Every syntax read bit for bit: the native ones, JPEG Lossless (SV1 and any predictor), JPEG-LS
#: lossless, JPEG 2000 (reversible, under both of its UIDs) and RLE. (A lossless JPEG-LS stream
#: under the near-lossless UID, NEAR 0, is read too; no encoder here writes one.)
LOSSLESS = NATIVE + [uid for uid in COMPRESSED if uid != "1.2.840.10008.1.2.4.81"]


@pytest.fixture(scope="module")
def cine(tmp_path_factory):
    """A two-frame 12-bit XA cine of plane A: smooth anatomy-like line integrals with noise."""
    view = View.from_gantry(25.0, -10.0, shape=(64, 80), pixel_mm=2.5, name="A")
    rng = np.random.default_rng(7)
    v, u = np.mgrid[:64, :80]
    L = np.stack([1.5 + np.sin(u / (7.0 + k)) * np.cos(v / 9.0) + rng.normal(0, 0.05, (64, 80)) for k in range(2)])
    counts = detector_counts(np.clip(L, 0.0, 4.0))
    path = write_xa(tmp_path_factory.mktemp("cine") / "A.dcm", view, counts, frame_time_ms=66.7, uid_seed="syntaxes")
    return {"view": view, "counts": counts, "path": path}


def test_the_receivable_syntaxes_are_those_pydicom_decodes_here():
    assert RECEIVABLE_TRANSFER_SYNTAXES[:len(NATIVE)] == ("1.2.840.10008.1.2.1", "1.2.840.10008.1.2",
                                                          "1.2.840.10008.1.2.1.99", "1.2.840.10008.1.2.2")
    assert set(RECEIVABLE_TRANSFER_SYNTAXES) == set(NATIVE) | {u for u in COMPRESSED if get_decoder(u).is_available}
    assert set(COMPRESSED) <= set(RECEIVABLE_TRANSFER_SYNTAXES)  # python-gdcm (a dependency) decodes them all


def _compressed(cine, tmp_path, syntax):
    path = tmp_path / "compressed.dcm"
    if compress(cine["path"], path, syntax) is None:
        pytest.skip(f"no encoder for {syntax} here (DCMTK, pydicom's or Pillow's)")
    assert str(pydicom.dcmread(path, stop_before_pixels=True).file_meta.TransferSyntaxUID) == syntax
    return path


@pytest.mark.parametrize("syntax", LOSSLESS)
def test_each_lossless_syntax_is_read_bit_for_bit_by_load_frame_and_the_receiver(cine, tmp_path, syntax):
    path = _compressed(cine, tmp_path, syntax)
    view, counts = cine["view"], cine["counts"]
    for k in range(len(counts)):  # the stored values, frame by frame
        np.testing.assert_array_equal(load_frame(path, view, frame_index=k).image, counts[k].astype(np.float32))
    # the receiver's decoding of the same object gives the line integrals load_frame gives the original
    received = decode_xray_object(pydicom.dcmread(path), [view], air_value=4095.0)
    for frame in received:
        original = load_frame(cine["path"], view, frame_index=frame.frame_index, line_integrals=False,
                              air_value=4095.0)
        np.testing.assert_array_equal(frame.image, original.image)
    assert [f.view.name for f in received] == ["A", "A"]


def test_near_lossless_jpeg_ls_decodes_within_its_near_and_is_refused_by_every_reader(cine, tmp_path):
    path = _compressed(cine, tmp_path, "1.2.840.10008.1.2.4.81")
    ds = pydicom.dcmread(path)
    near = jpeg_ls_near(path)
    assert near == NEAR
    assert np.abs(xray_pixels(ds).astype(int) - cine["counts"]).max() <= near  # decoded within its bound
    # DCMTK also marks the object LossyImageCompression 01; without that tag its stream tells
    reason = r"lossy pixels are refused: its (LossyImageCompression \(0028,2110\) is 01: its pixels were " \
             r"compressed lossily|JPEG-LS stream is near-lossless \(NEAR 2\): send it lossless)"
    with pytest.raises(XRayObjectRejected, match=f"^path '.*compressed.dcm': {reason}$"):
        load_frame(path, cine["view"], frame_index=0)  # histostudy pose, calibrate
    with pytest.raises(XRayObjectRejected, match=f"^{reason}$") as refused:
        decode_xray_object(ds, [cine["view"]])  # histostudy listen
    assert refused.value.status == 0xA900
    if "LossyImageCompression" in ds:
        del ds.LossyImageCompression
    with pytest.raises(XRayObjectRejected, match=r"^lossy pixels are refused: its JPEG-LS stream is near-lossless"):
        decode_xray_object(ds, [cine["view"]])


def test_irreversible_jpeg_2000_is_refused_and_reversible_read(cine, tmp_path):
    from PIL import features

    if not features.check("jpg_2000"):
        pytest.skip("Pillow without OpenJPEG")
    from xa_codecs import _pillow_j2k

    ds = pydicom.dcmread(cine["path"])
    _pillow_j2k(ds, tmp_path / "lossy.dcm", "1.2.840.10008.1.2.4.91", irreversible=True)
    with pytest.raises(XRayObjectRejected, match=r"its JPEG 2000 stream is irreversible \(9-7 wavelet\)"):
        load_frame(tmp_path / "lossy.dcm", cine["view"], frame_index=0)
    ds.LossyImageCompression = "01"  # a lossy past, whatever the syntax now
    with pytest.raises(XRayObjectRejected, match=r"its LossyImageCompression \(0028,2110\) is 01"):
        check_xray_object(ds)


@pytest.mark.parametrize("syntax, reason", [
    ("1.2.840.10008.1.2.4.50", r"transfer syntax 1\.2\.840\.10008\.1\.2\.4\.50 \(JPEG Baseline.*"
                               r"lossy JPEG \(baseline\) is refused"),
    ("1.2.840.10008.1.2.4.51", r"lossy JPEG \(extended\) is refused"),
    ("1.2.3.4", r"transfer syntax 1\.2\.3\.4: not one this reader decodes"),
])
def test_lossy_jpeg_and_unknown_syntaxes_are_refused_naming_them(cine, syntax, reason):
    ds = pydicom.dcmread(cine["path"])
    ds.file_meta.TransferSyntaxUID = syntax
    with pytest.raises(XRayObjectRejected, match=reason) as refused:
        check_xray_object(ds, source="path 'A.dcm'")
    assert refused.value.status == 0xA900 and str(refused.value).startswith("path 'A.dcm': its pixel data cannot")
