"""Compressed XA objects over the network: a pair compressed as JPEG Lossless (first-order
prediction, 1.2.840.10008.1.2.4.70) and as RLE Lossless (1.2.840.10008.1.2.5) — by DCMTK's
``dcmcjpeg``/``dcmcrle`` where installed, else by pydicom's encoders (tests/imaging/io/xa_codecs.py)
— is sent to the live receiver with :func:`histostudy.lab.send_frames` and with DCMTK's
``storescu`` (where installed), in its compressed syntax, and gets the lines of the uncompressed pair.

The pose work is receiver_stub.py's stub tracker, whose focal point holds the mean of each plane's
line integrals: equal lines mean equal pixels, decoded bit for bit on the receiver's side.

The compressed objects keep the uncompressed ones' SOP Instance UIDs, as a C-arm recompressing its own
object would (pydicom's ``Dataset.compress`` gives a new one by default, DCMTK's codecs keep it), so the
lines' ``instance_uids`` compare equal with or without DCMTK.

Regression: ``send_frames`` proposed a compressed object's syntax beside the native ones in one
presentation context; the receiver, which prefers a native syntax, chose one, and pynetdicom, which
sends a compressed object only as it is, refused to store it. It now proposes it in its own context.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pydicom
import pytest
from receiver_stub import StubTracker, pair_objects, read_lines, receiver_with, small_views

import histostudy.lab.receiver as receiver_module
from histostudy.imaging.io import RECEIVABLE_TRANSFER_SYNTAXES
from histostudy.lab import send_frames

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "imaging" / "io"))  # the readers' tests' encoders
from xa_codecs import compress  # noqa: E402

SYNTAXES = {"jpeg_lossless": "1.2.840.10008.1.2.4.70", "rle": "1.2.840.10008.1.2.5"}
#: storescu's option proposing each (in a context of its own, beside the uncompressed ones').
STORESCU_PROPOSE = {"jpeg_lossless": "-xs", "rle": "-xr"}
EXPLICIT_LE = "1.2.840.10008.1.2.1"
#: The fields of a line that the pixels, the frames' times and the objects decide (not its seconds).
FIELDS = ("pair_index", "planes", "instance_uids", "frame_indices", "frame_times", "accepted", "focal_point_mm",
          "T_carm_transducer", "tracking")


@pytest.fixture(scope="module")
def views():
    return small_views()


@pytest.fixture(scope="module")
def pair(views, tmp_path_factory):
    """Two pairs (0 and 1) of single-frame XA objects as files, uncompressed (explicit VR little endian)."""
    folder = tmp_path_factory.mktemp("pair")
    paths = []
    for k in (0, 1):
        for ds in pair_objects(views, k):
            paths.append(folder / f"{k}{ds.SeriesDescription}.dcm")
            ds.save_as(paths[-1], enforce_file_format=True)
    return paths


@pytest.fixture
def syntaxes_received(monkeypatch):
    """The transfer syntax of each object the receiver reads, as it came off the network."""
    received = []
    read = receiver_module.read_c_store

    def recording(event, *args, **kwargs):
        received.append(str(event.file_meta.TransferSyntaxUID))
        return read(event, *args, **kwargs)

    monkeypatch.setattr(receiver_module, "read_c_store", recording)
    return received


def compress_keeping_uid(src: Path, dst: Path, syntax: str) -> str | None:
    """``xa_codecs.compress``, then ``dst`` given back ``src``'s SOP Instance UID (in the dataset and its
    file meta) where the encoder gave it a new one; the encoder used, or None."""
    encoder = compress(src, dst, syntax)
    if encoder is not None:
        uid = pydicom.dcmread(src, stop_before_pixels=True).SOPInstanceUID
        ds = pydicom.dcmread(dst)
        if ds.SOPInstanceUID != uid:
            ds.SOPInstanceUID = uid
            ds.file_meta.MediaStorageSOPInstanceUID = uid
            ds.save_as(dst, enforce_file_format=True)
    return encoder


def lines_of(views, folder: Path, paths, sender: str, name: str | None = None) -> list[dict]:
    """The lines a receiver writes for ``paths`` sent by ``sender`` (``send_frames`` or ``storescu``,
    proposing the syntax ``name``)."""
    folder.mkdir()
    with receiver_with(views, folder, StubTracker(), max_queued_pairs=None, warm_up=False) as receiver:
        if sender == "storescu":  # -R: only the files' SOP class
            done = subprocess.run(["storescu", "-R", STORESCU_PROPOSE[name], "-aec", "HISTOSTUDY", "127.0.0.1",
                                   str(receiver.port), *map(str, paths)], capture_output=True, text=True, timeout=60)
            assert done.returncode == 0, done.stderr
        else:
            assert send_frames(paths, "127.0.0.1", receiver.port, calling_ae_title="TESTSCU") == [0] * len(paths)
        assert receiver.wait_for_pairs(len(paths) // 2, timeout_s=60)
    stats = receiver.stats()
    assert (stats["objects_rejected"], stats["pairs_errors"], stats["frames_unpaired"]) == (0, 0, 0)
    return [{key: line[key] for key in FIELDS} for line in read_lines(folder / "poses.jsonl")]


@pytest.mark.parametrize("sender", ["send_frames", "storescu"])
@pytest.mark.parametrize("name", sorted(SYNTAXES))
def test_a_compressed_pair_sent_gets_the_lines_of_the_uncompressed_pair(views, pair, tmp_path, syntaxes_received,
                                                                        name, sender):
    syntax = SYNTAXES[name]
    if syntax not in RECEIVABLE_TRANSFER_SYNTAXES:
        pytest.skip(f"no decoder for {name} in this install: the receiver does not negotiate it")
    if sender == "storescu" and not shutil.which("storescu"):
        pytest.skip("DCMTK's storescu is not installed")
    compressed = [tmp_path / f"{name}-{path.name}" for path in pair]
    encoders = {compress_keeping_uid(src, dst, syntax) for src, dst in zip(pair, compressed)}
    if None in encoders:
        pytest.skip(f"neither DCMTK nor pydicom can write {name} here")
    expected = lines_of(views, tmp_path / "uncompressed", pair, "send_frames")
    assert syntaxes_received == [EXPLICIT_LE] * len(pair)
    syntaxes_received.clear()
    assert lines_of(views, tmp_path / name, compressed, sender, name) == expected
    assert syntaxes_received == [syntax] * len(pair)  # as compressed on the wire, decoded by the receiver
    assert [line["pair_index"] for line in expected] == [0, 1] and all(line["accepted"] for line in expected)
