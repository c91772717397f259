"""Pixels stored by other encoders than ours: pydicom's own test files, read from the installed
pydicom (not shipped here; pydicom/data/test_files/README.txt names their sources and licences).
Its MR_small image, compressed by GDCM and dcmtk in RLE, JPEG-LS lossless and JPEG 2000
reversible, decodes to its uncompressed values bit for bit; a JPEG-LS near-lossless and a JPEG 2000
irreversible stream, stored as X-ray images, are refused for their lossy pixels, by their tag or
else by their stream; and every reader of the lab's frames refuses an object that is not an X-ray
image with the same reason (docs/your-data.md)."""

import copy

import numpy as np
import pydicom
import pytest
from pydicom.data import get_testdata_file
from xa_codecs import jpeg_ls_near

from histostudy.imaging import View, load_frame
from histostudy.imaging.io import XRayObjectRejected, check_xray_object, xray_pixels
from histostudy.lab.xray_objects import decode_xray_object

#: MR_small (64 x 64, 16 bits, signed) uncompressed, and its lossless compressions by others.
REFERENCE = "MR_small.dcm"
LOSSLESS = {"MR_small_RLE.dcm": "1.2.840.10008.1.2.5", "MR_small_jpeg_ls_lossless.dcm": "1.2.840.10008.1.2.4.80",
            "MR_small_jp2klossless.dcm": "1.2.840.10008.1.2.4.90"}
#: A JPEG-LS near-lossless stream (no LossyImageCompression tag) and a JPEG 2000 irreversible one (tagged).
LOSSY = {"JPEGLSNearLossless_16.dcm": "1.2.840.10008.1.2.4.81", "JPEG2000.dcm": "1.2.840.10008.1.2.4.91"}
NOT_XRAY = r"SOP class [0-9.]+ \((MR|CT|Secondary Capture) Image Storage\) is not an X-ray angiographic or RF image"
XA_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.12.1"


def _read(name):
    return pydicom.dcmread(get_testdata_file(name))


@pytest.mark.parametrize("name", sorted(LOSSLESS))
def test_each_lossless_file_of_another_encoder_decodes_to_the_uncompressed_values_bit_for_bit(name):
    ds, reference = _read(name), xray_pixels(_read(REFERENCE))
    assert str(ds.file_meta.TransferSyntaxUID) == LOSSLESS[name]
    pixels = xray_pixels(ds)
    assert pixels.shape == (64, 64) and pixels.dtype == reference.dtype == np.int16 and np.ptp(reference) > 1000
    np.testing.assert_array_equal(pixels, reference)
    np.testing.assert_array_equal(xray_pixels(ds, 0), pixels)  # the frame by its index


@pytest.mark.parametrize("name", sorted(LOSSY))
def test_lossy_pixels_stored_as_an_x_ray_image_are_refused_by_their_tag_or_their_stream(name):
    ds = _read(name)
    assert str(ds.file_meta.TransferSyntaxUID) == LOSSY[name]
    if name.startswith("JPEGLS"):
        assert jpeg_ls_near(get_testdata_file(name)) > 0  # what the stream says, read independently
    lossy = copy.deepcopy(ds)
    lossy.SOPClassUID = lossy.file_meta.MediaStorageSOPClassUID = XA_IMAGE_STORAGE
    if "LossyImageCompression" in lossy:
        with pytest.raises(XRayObjectRejected, match=r"lossy pixels are refused: its LossyImageCompression"):
            check_xray_object(lossy)
        del lossy.LossyImageCompression
    with pytest.raises(XRayObjectRejected, match=r"near-lossless \(NEAR [1-9][0-9]*\)|irreversible \(9-7 wavelet\)"):
        check_xray_object(lossy)


@pytest.mark.parametrize("name", [REFERENCE, *sorted(LOSSLESS), *sorted(LOSSY)])
def test_every_reader_refuses_an_object_that_is_not_an_x_ray_image_with_the_same_reason(name, tmp_path):
    path = get_testdata_file(name)
    ds = pydicom.dcmread(path)
    view = View.from_gantry(0.0, 0.0, shape=(int(ds.Rows), int(ds.Columns)), pixel_mm=0.2, name="A")
    with pytest.raises(XRayObjectRejected, match=NOT_XRAY) as refused:
        check_xray_object(ds)
    assert refused.value.status == 0x0122
    for read in (lambda: View.from_dicom(path), lambda: load_frame(path, view),  # histostudy pose, calibrate
                 lambda: decode_xray_object(ds, [view])):  # histostudy listen
        with pytest.raises(XRayObjectRejected, match=NOT_XRAY):
            read()
    # without SOPClassUID it is still what its file meta says it was stored as: refused alike
    del ds.SOPClassUID
    for read in (lambda: check_xray_object(ds), lambda: View.from_dicom(ds)):
        with pytest.raises(XRayObjectRejected, match=NOT_XRAY):
            read()
    # as a bare image (no SOP class anywhere) its geometry is what is missing, named with its tag
    del ds.file_meta.MediaStorageSOPClassUID
    with pytest.raises(ValueError, match=r"lacks PositionerPrimaryAngle \(0018,1510\), which a view needs"):
        View.from_dicom(ds)
