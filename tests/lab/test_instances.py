"""Tests of histostudy.lab.instances: an X-ray object sent again is recognised by its SOP Instance
UID and pixels, in its own transfer syntax or another, and a UID reused for other pixels is refused."""

import copy
import datetime as dt

import numpy as np
import pytest
from pydicom.uid import ImplicitVRLittleEndian, RLELossless

from histostudy.imaging import default_biplane
from histostudy.imaging.io._xa import xa_dataset
from histostudy.lab.instances import InstanceRegister, pixel_fingerprint
from histostudy.lab.xray_objects import STATUS_DUPLICATE_INSTANCE, XRayObjectRejected

UID = "1.2.3.4"


@pytest.fixture(scope="module")
def native():
    view = default_biplane(shape=(48, 62), pixel_mm=6.16)[0]
    counts = np.random.default_rng(0).integers(100, 4000, size=(2,) + view.shape).astype(np.uint16)
    return xa_dataset(view, counts, acquisition_time=dt.datetime(2024, 5, 6, 10, 30), frame_time_ms=40.0,
                      uid_seed="instances")


def _as(dataset, syntax):
    out = copy.deepcopy(dataset)
    if syntax == RLELossless:
        out.compress(RLELossless)
    else:
        out.file_meta.TransferSyntaxUID = syntax
    return out


def _other_pixels(dataset):
    out = copy.deepcopy(dataset)
    pixels = out.pixel_array.copy()
    pixels[0, 0, 0] += 1  # one pixel of one frame
    out.PixelData = pixels.tobytes()
    return out


def _refusal(register, fingerprint, match):
    with pytest.raises(XRayObjectRejected, match=match) as refused:
        register.admit(UID, fingerprint)
    assert refused.value.status == STATUS_DUPLICATE_INSTANCE == 0x0111
    assert UID in refused.value.reason


def test_the_same_object_again_is_a_duplicate_and_other_pixels_under_its_uid_are_refused(native):
    register = InstanceRegister()
    assert register.admit(UID, pixel_fingerprint(native)) is True
    assert register.admit(UID, pixel_fingerprint(copy.deepcopy(native))) is False
    assert register.admit("1.2.3.5", pixel_fingerprint(native)) is True  # another UID is another instance
    _refusal(register, pixel_fingerprint(_other_pixels(native)), "received before with other pixels")
    assert len(register) == 2 and UID in register


def test_native_syntaxes_compare_by_their_bytes_and_a_compressed_copy_by_its_decoded_pixels(native):
    register = InstanceRegister()
    register.admit(UID, pixel_fingerprint(native))
    implicit = pixel_fingerprint(_as(native, ImplicitVRLittleEndian))
    assert not register.needs_decoding(UID, implicit) and register.admit(UID, implicit) is False
    rle = _as(native, RLELossless)
    assert register.needs_decoding(UID, pixel_fingerprint(rle))
    assert register.admit(UID, pixel_fingerprint(rle, decode=True)) is False
    _refusal(register, pixel_fingerprint(_as(_other_pixels(native), RLELossless), decode=True), "other pixels")


def test_a_compressed_first_copy_cannot_be_compared_with_another_syntax_and_is_refused(native):
    register = InstanceRegister()
    rle = _as(native, RLELossless)
    register.admit(UID, pixel_fingerprint(rle))
    assert register.admit(UID, pixel_fingerprint(_as(native, RLELossless))) is False  # its own syntax: bytes
    assert not register.needs_decoding(UID, pixel_fingerprint(native))
    _refusal(register, pixel_fingerprint(native), "cannot be compared")


def test_another_pixel_shape_is_refused_and_the_oldest_instance_is_forgotten_first(native):
    register = InstanceRegister(max_instances=2)
    register.admit(UID, pixel_fingerprint(native))
    single = copy.deepcopy(native)
    single.NumberOfFrames = 1
    single.PixelData = native.PixelData[:len(native.PixelData) // 2]
    _refusal(register, pixel_fingerprint(single), "another pixel shape")
    register.admit("2", pixel_fingerprint(native))
    register.admit("3", pixel_fingerprint(native))
    assert UID not in register and len(register) == 2
    assert register.admit(UID, pixel_fingerprint(single)) is True  # forgotten: taken as new


def test_undecodable_pixels_are_refused_when_they_must_be_compared(native):
    broken = _as(native, RLELossless)
    broken.PixelData = broken.PixelData[:40]
    with pytest.raises(XRayObjectRejected, match="cannot be decoded") as refused:
        pixel_fingerprint(broken, decode=True)
    assert refused.value.status == 0xA900


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, None])
def test_a_register_of_no_instances_is_refused(bad):
    with pytest.raises(ValueError, match="max_instances must be an integer >= 1"):
        InstanceRegister(bad)
