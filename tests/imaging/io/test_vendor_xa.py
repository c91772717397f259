"""Real X-ray angiography pixels as stored by others (tests/data/vendor_xa, README.md there): the
DICOM WG-04 compression samples' XA1 image in six transfer syntaxes. The lossless ones decode to
the uncompressed reference bit for bit (its SHA-256), the near-lossless one within the NEAR of its
stream, the lossy JPEG 2000 one close to it; and all six, secondary captures without positioner or
distance tags, are refused by every reader of the lab's frames with the same reason (and the two
lossy ones, were they X-ray images, for their lossy pixels)."""

import copy
import hashlib
from pathlib import Path

import numpy as np
import pydicom
import pytest
from xa_codecs import jpeg_ls_near

from histostudy.imaging import View, load_frame
from histostudy.imaging.io import XRayObjectRejected, check_xray_object, xray_pixels
from histostudy.lab.xray_objects import decode_xray_object

VENDOR = Path(__file__).resolve().parents[2] / "data" / "vendor_xa"
#: SHA-256 of the stored values (uint16, little endian, 1024 x 1024) of WG-04's uncompressed
#: reference REF/XA1_UNC, of which the files below are compressions.
REFERENCE_SHA256 = "797b3375a2d1f94ccac04c657b5b5d90d9b4051f76508c867f2dea465d1a7f3b"
LOSSLESS = {"XA1_JPLL": "1.2.840.10008.1.2.4.70", "XA1_JLSL": "1.2.840.10008.1.2.4.80",
            "XA1_J2KR": "1.2.840.10008.1.2.4.90", "XA1_RLE": "1.2.840.10008.1.2.5"}
LOSSY = {"XA1_JLSN": "1.2.840.10008.1.2.4.81", "XA1_J2KI": "1.2.840.10008.1.2.4.91"}
SECONDARY_CAPTURE = (r"SOP class 1\.2\.840\.10008\.5\.1\.4\.1\.1\.7 \(Secondary Capture Image Storage\) "
                     r"is not an X-ray angiographic or RF image")


def _pixels(name):
    return xray_pixels(pydicom.dcmread(VENDOR / name))


@pytest.fixture(scope="module")
def reference():
    return _pixels("XA1_RLE")  # pydicom's own RLE decoder; its hash is checked below


@pytest.mark.parametrize("name", sorted(LOSSLESS))
def test_each_lossless_vendor_file_decodes_to_the_uncompressed_reference_bit_for_bit(name):
    ds = pydicom.dcmread(VENDOR / name)
    assert str(ds.file_meta.TransferSyntaxUID) == LOSSLESS[name] and ds.Modality == "XA"
    pixels = xray_pixels(ds)
    assert pixels.shape == (1024, 1024) and pixels.dtype == np.uint16 and int(pixels.max()) < 2 ** int(ds.BitsStored)
    assert hashlib.sha256(pixels.astype("<u2").tobytes()).hexdigest() == REFERENCE_SHA256
    np.testing.assert_array_equal(xray_pixels(ds, 0), pixels)  # the frame by its index


def test_near_lossless_jpeg_ls_is_within_its_near_and_lossy_jpeg_2000_close(reference):
    near = jpeg_ls_near(VENDOR / "XA1_JLSN")
    error = np.abs(_pixels("XA1_JLSN").astype(int) - reference)
    assert near == 4 and 0 < error.max() <= near
    error = np.abs(_pixels("XA1_J2KI").astype(int) - reference)  # irreversible: no bound per value
    assert error.max() > 0 and np.sqrt(np.mean(error ** 2.0)) < 0.01 * (int(reference.max()) - int(reference.min()))


@pytest.mark.parametrize("name", sorted(LOSSLESS) + sorted(LOSSY))
def test_every_reader_refuses_a_secondary_capture_with_the_same_reason(name):
    path = VENDOR / name
    view = View.from_gantry(0.0, 0.0, shape=(1024, 1024), pixel_mm=0.2, name="A")
    ds = pydicom.dcmread(path)
    with pytest.raises(XRayObjectRejected, match=SECONDARY_CAPTURE) as refused:
        check_xray_object(ds)
    assert refused.value.status == 0x0122
    for read in (lambda: View.from_dicom(path), lambda: load_frame(path, view),  # histostudy pose, calibrate
                 lambda: decode_xray_object(ds, [view])):  # histostudy listen
        with pytest.raises(XRayObjectRejected, match=SECONDARY_CAPTURE):
            read()
    if name in LOSSY:  # stored as an XA image, its lossy pixels are refused: by its tag, else by its stream
        lossy = copy.deepcopy(ds)
        lossy.SOPClassUID = lossy.file_meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.12.1"
        with pytest.raises(XRayObjectRejected, match=r"lossy pixels are refused: its LossyImageCompression"):
            check_xray_object(lossy)
        del lossy.LossyImageCompression
        with pytest.raises(XRayObjectRejected, match=r"near-lossless \(NEAR 4\)|irreversible \(9-7 wavelet\)"):
            check_xray_object(lossy)
    # without SOPClassUID it is still what its file meta says it was stored as: refused alike
    del ds.SOPClassUID
    for read in (lambda: check_xray_object(ds), lambda: View.from_dicom(ds)):
        with pytest.raises(XRayObjectRejected, match=SECONDARY_CAPTURE):
            read()
    # as a bare image (no SOP class anywhere) its geometry is what is missing, named with its tag
    del ds.file_meta.MediaStorageSOPClassUID
    with pytest.raises(ValueError, match=r"lacks PositionerPrimaryAngle \(0018,1510\), which a view needs"):
        View.from_dicom(ds)
