"""An XA file rewritten in another transfer syntax, for the tests of the readers: by DCMTK's
command-line codecs where installed (encoders independent of the decoders under test), else by
pydicom's own encoders (``Dataset.compress``) where this install has one, else, for JPEG 2000, by
Pillow's OpenJPEG encoder (reversible); ``None`` where none can."""

import io
import shutil
import struct
import subprocess

import numpy as np
import pydicom

#: DCMTK's command for each transfer syntax (source and destination paths appended).
DCMTK = {
    "1.2.840.10008.1.2": ["dcmconv", "+ti"],
    "1.2.840.10008.1.2.1.99": ["dcmconv", "+td"],
    "1.2.840.10008.1.2.2": ["dcmconv", "+tb"],
    "1.2.840.10008.1.2.4.70": ["dcmcjpeg", "+e1"],
    "1.2.840.10008.1.2.4.57": ["dcmcjpeg", "+el"],
    "1.2.840.10008.1.2.4.80": ["dcmcjpls", "+el"],
    "1.2.840.10008.1.2.4.81": ["dcmcjpls", "+en", "+md", "2"],
    "1.2.840.10008.1.2.5": ["dcmcrle"],
}
#: The NEAR (largest error per stored value) that the near-lossless encodings above use.
NEAR = 2


def compress(src, dst, syntax: str) -> str | None:
    """Write ``src`` in transfer syntax ``syntax`` to ``dst``; the encoder used, or None."""
    if str(pydicom.dcmread(src, stop_before_pixels=True).file_meta.TransferSyntaxUID) == syntax:
        shutil.copyfile(src, dst)
        return "copy"
    command = DCMTK.get(syntax)
    if command and shutil.which(command[0]):
        subprocess.run([*command, str(src), str(dst)], check=True, capture_output=True)
        assert str(pydicom.dcmread(dst, stop_before_pixels=True).file_meta.TransferSyntaxUID) == syntax
        return "dcmtk"
    from pydicom.pixels import get_encoder

    ds = pydicom.dcmread(src)
    try:
        encoder = get_encoder(syntax)
    except NotImplementedError:  # a syntax pydicom has no encoder for
        encoder = None
    if encoder is not None and encoder.is_available:
        kwargs = {"jls_error": NEAR} if syntax == "1.2.840.10008.1.2.4.81" else {}
        ds.compress(syntax, **kwargs)
        ds.save_as(dst, enforce_file_format=True)
        return "pydicom"
    if syntax in ("1.2.840.10008.1.2.4.90", "1.2.840.10008.1.2.4.91"):
        return _pillow_j2k(ds, dst, syntax)
    return None


def _pillow_j2k(ds, dst, syntax: str, irreversible: bool = False) -> str | None:
    """Each frame as a JPEG 2000 codestream by Pillow (OpenJPEG; reversible unless
    ``irreversible``), encapsulated."""
    from PIL import Image, features
    from pydicom.encaps import encapsulate

    if not features.check("jpg_2000"):
        return None
    pixels = ds.pixel_array.reshape((-1, int(ds.Rows), int(ds.Columns)))
    streams = []
    for frame in pixels:
        out = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(frame, dtype=np.uint16)).save(out, format="JPEG2000", no_jp2=True,
                                                                           irreversible=irreversible)
        streams.append(out.getvalue())
    ds.PixelData = encapsulate(streams)
    ds["PixelData"].VR = "OB"
    ds.file_meta.TransferSyntaxUID = syntax
    ds.save_as(dst, enforce_file_format=True)
    return "pillow"


def jpeg_ls_near(path) -> int:
    """The NEAR parameter of the first JPEG-LS scan (SOS marker) in a file's pixel data."""
    data = bytes(pydicom.dcmread(path).PixelData)
    start = data.find(b"\xff\xda")
    length = struct.unpack(">H", data[start + 2:start + 4])[0]
    segment = data[start + 4:start + 2 + length]
    return segment[1 + 2 * segment[0]]
