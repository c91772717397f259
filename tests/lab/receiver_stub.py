"""What the receiver's fast tests share (tests/lab/test_receiver_*.py): a stub tracker instead of
the learned stages, small biplane views, a pair of small single-frame XA objects per instant, a
receiver made with the stub, the pose lines written, a free TCP port; and, for the fuzz
(test_receiver_fuzz.py, benchmarks/bench_receiver_fuzz.py), a raw DICOM client, the hostile
associations it makes, each a seeded draw that can be replayed, and :func:`run_fuzz`."""

import collections
import datetime as dt
import io
import json
import socket
import struct
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import numpy as np

from histostudy.imaging import default_biplane
from histostudy.imaging.io._xa import xa_dataset
from histostudy.lab import FrameReceiver, ReceiverConfig

T0 = dt.datetime(2024, 5, 6, 10, 30, 0)
INTERVAL_S = 0.1  # between pairs: more than the pairing's tolerance, so each pair is its own


class StubTracker:
    """What the receiver asks of a Tracker (``track``, ``stats``, ``last_kind``), without pose work:
    each pair's result has a focal point of (index, mean of the first image, mean of the second)
    (index from 1; the means tell the pixels received). With ``hold``, the first pair is held until
    ``release`` is set (``taken`` is set once it is). ``keep_images=False``: the images are not
    kept (``n`` counts the pairs), so that a long run's memory stays flat."""

    def __init__(self, hold: bool = False, keep_images: bool = True):
        self.hold, self.taken, self.release = hold, threading.Event(), threading.Event()
        self.images, self.last_kind, self.keep_images, self.n = [], None, keep_images, 0

    def stats(self) -> dict:
        return {"stage_seconds": {}, "n_updates": self.n}

    def track(self, pairs, *, ready=None):
        for images in pairs:
            self.n += 1
            if self.keep_images:
                self.images.append(images)
            self.taken.set()
            if self.hold and self.n == 1:
                assert self.release.wait(30)
            self.last_kind = "from_scratch" if self.n == 1 else "warm"
            verdict = SimpleNamespace(ok=True, reasons=[], rms_distance_px=[1.0, 1.0],
                                      view_disagreement_mm=[0.1, 0.1], view_gain_px2=[0.0, 0.0],
                                      unexplained_fraction=[0.0, 0.0])
            focal = np.array([self.n, *(float(np.mean(image)) for image in images[:2])])
            yield SimpleNamespace(T_carm_transducer=np.eye(4), focal_point_mm=focal, cost=0.0, verdict=verdict,
                                  timings_s={"total": 0.0})


def small_views():
    """The paper's biplane on a small detector: fast to send and decode."""
    return default_biplane(shape=(48, 62), pixel_mm=6.16)


def pair_objects(views, k: int, blank: bool = False) -> list:
    """Pair ``k``: one single-frame XA object per plane, taken ``k`` intervals after T0."""
    rng = np.random.default_rng(k)
    objects = []
    for view in views:
        counts = rng.integers(100, 4000, size=view.shape).astype(np.uint16)
        ds = xa_dataset(view, counts, acquisition_time=T0 + dt.timedelta(seconds=k * INTERVAL_S),
                        uid_seed=f"pair{k}/{view.name}/{blank}")
        if blank:
            ds.PixelData = bytes(len(ds.PixelData))
        objects.append(ds)
    return objects


def receiver_with(views, tmp_path, tracker, **options) -> FrameReceiver:
    """A receiver on a free loopback port writing ``tmp_path/poses.jsonl``, its tracker ``tracker``."""
    options.setdefault("warm_up", False)  # a stub tracker has nothing to warm up
    receiver = FrameReceiver(views, ReceiverConfig(output_path=tmp_path / "poses.jsonl", port=0, tolerance_s=0.02,
                                                   **options))
    receiver.tracker = tracker
    return receiver


def wait_for_count(receiver, key: str, n: int, timeout_s: float = 30.0) -> dict:
    """The receiver's stats once ``stats()[key]`` reaches ``n`` (or at ``timeout_s``): a refusal is
    counted on the connection's thread, which may run after the peer has already seen it."""
    deadline = time.monotonic() + timeout_s
    while receiver.stats()[key] < n and time.monotonic() < deadline:
        time.sleep(0.02)
    return receiver.stats()


def read_lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def free_port() -> int:
    """A TCP port nothing listens on (bound, then closed)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


# --- the fuzz: a raw DICOM client (PS3.8's PDUs by hand, so that any of them can be broken) ---------

XA_STORAGE = "1.2.840.10008.5.1.4.1.1.12.1"
VERIFICATION = "1.2.840.10008.1.1"
EXPLICIT_LE = "1.2.840.10008.1.2.1"
#: When the hostile objects were taken: a day before the good pairs, so that one the receiver
#: accepts (a garbled tag it tolerates) is dropped unpaired and never pairs with a good frame.
HOSTILE_T0 = T0 - dt.timedelta(days=1)
#: How long a hostile client waits for the receiver (s): reaching it means the receiver hung.
CLIENT_TIMEOUT_S = 30.0
#: Explicit VRs with a 4-byte length (PS3.5 §7.1.2); the others have a 2-byte one.
LONG_VRS = {b"OB", b"OD", b"OF", b"OL", b"OV", b"OW", b"SQ", b"SV", b"UC", b"UN", b"UR", b"UT", b"UV"}


def pdu(kind: int, body: bytes, length: int | None = None) -> bytes:
    """A PDU: type, reserved byte, the 4-byte length (``length``, or the body's), the body."""
    return bytes([kind, 0]) + (len(body) if length is None else length).to_bytes(4, "big") + body


def _item(kind: int, body: bytes) -> bytes:
    return bytes([kind, 0]) + len(body).to_bytes(2, "big") + body


def associate_rq(abstract: str = XA_STORAGE, syntax: str = EXPLICIT_LE, called: str = "HISTOSTUDY",
                 calling: str = "FUZZ") -> bytes:
    """An A-ASSOCIATE-RQ proposing ``abstract`` in transfer syntax ``syntax`` (context ID 1)."""
    context = bytes([1, 0, 0, 0]) + _item(0x30, abstract.encode()) + _item(0x40, syntax.encode())
    user = _item(0x51, (16384).to_bytes(4, "big")) + _item(0x52, b"1.2.826.0.1.3680043.9.7156.1")
    body = (b"\x00\x01\x00\x00" + called.ljust(16).encode() + calling.ljust(16).encode() + bytes(32)
            + _item(0x10, b"1.2.840.10008.3.1.1.1") + _item(0x20, context) + _item(0x50, user))
    return pdu(0x01, body)


def pdata(control: int, data: bytes) -> bytes:
    """A P-DATA-TF PDU of one PDV of context 1: ``control`` bit 0 a command, bit 1 the last fragment."""
    return pdu(0x04, (len(data) + 2).to_bytes(4, "big") + bytes([1, control]) + data)


def command_bytes(field: int, sop_class: str | None, uid: str | None = None, has_data: bool = True) -> bytes:
    """A DIMSE request's command set (implicit VR little endian): C-STORE-RQ 0x0001, C-ECHO-RQ 0x0030."""
    from pydicom.dataset import Dataset
    from pynetdicom.dsutils import encode

    command = Dataset()
    command.CommandGroupLength = 0
    if sop_class is not None:
        command.AffectedSOPClassUID = sop_class
    command.CommandField, command.MessageID = field, 1
    if uid is not None:
        command.Priority, command.AffectedSOPInstanceUID = 0, uid
    command.CommandDataSetType = 0x0000 if has_data else 0x0101
    command.CommandGroupLength = len(encode(command, True, True)) - 12
    return encode(command, True, True)


def read_pdu(sock) -> tuple[int, bytes] | None:
    """The next PDU's type and body; None once the receiver closed the connection."""
    head = _read(sock, 6)
    if len(head) < 6:
        return None
    body = _read(sock, int.from_bytes(head[2:], "big"))
    return head[0], body


def _read(sock, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = sock.recv(min(n - len(out), 65536))
        if not chunk:
            break
        out += chunk
    return out


def reaction(sock) -> str:
    """What the receiver did next: ``status 0x....`` (a DIMSE response), ``aborted`` (A-ABORT),
    ``rejected``, ``accepted``, ``released``, ``closed`` (the connection), ``reset``, or ``timeout``
    (nothing in :data:`CLIENT_TIMEOUT_S`: the receiver hung)."""
    from pynetdicom.dsutils import decode

    command = b""
    while True:
        try:
            got = read_pdu(sock)
        except TimeoutError:
            return "timeout"
        except OSError:
            return "reset"
        if got is None:
            return "closed"
        kind, body = got
        if kind != 0x04:
            return {0x02: "accepted", 0x03: "rejected", 0x06: "released", 0x07: "aborted"}.get(kind, f"pdu {kind}")
        at = 0
        while at + 6 <= len(body):
            length, control = int.from_bytes(body[at:at + 4], "big"), body[at + 5]
            command += body[at + 6:at + 4 + length] if control & 1 else b""
            if control & 3 == 3:
                return f"status 0x{int(decode(io.BytesIO(command), True, True).Status):04X}"
            at += 4 + length


def connect(port: int):
    return socket.create_connection(("127.0.0.1", port), timeout=CLIENT_TIMEOUT_S)


def associated(port: int, abstract: str = XA_STORAGE, syntax: str = EXPLICIT_LE):
    """A connection with an association accepted for ``abstract`` in ``syntax`` (context 1);
    AssertionError else. A transient rejection (A-ASSOCIATE-RJ result 2: pynetdicom's limit of
    associations at once reached) is tried again, as a C-arm's store queue does."""
    deadline = time.monotonic() + CLIENT_TIMEOUT_S
    while True:
        sock = connect(port)
        sock.sendall(associate_rq(abstract, syntax))
        got = read_pdu(sock)
        if got is None or got[0] != 0x03 or got[1][1] != 2 or time.monotonic() > deadline:
            break
        sock.close()
        time.sleep(0.2)
    # the A-ASSOCIATE-AC's presentation context item (0x21) after the 68 fixed bytes: result 0 accepted
    assert got is not None and got[0] == 0x02 and len(got[1]) > 68, f"association refused: {got}"
    at = 68
    while got[1][at] != 0x21:
        at += 4 + int.from_bytes(got[1][at + 2:at + 4], "big")
    assert got[1][at + 6] == 0, f"presentation context refused (result {got[1][at + 6]})"
    return sock


def echo(port: int) -> str:
    """A C-ECHO over the raw client: ``status 0x0000`` from a receiver that still serves."""
    with associated(port, VERIFICATION) as sock:
        sock.sendall(pdata(0x03, command_bytes(0x0030, VERIFICATION, has_data=False)))
        answer = reaction(sock)
        sock.sendall(pdu(0x05, bytes(4)))
        reaction(sock)
    return answer


def send_dataset(sock, uid: str, data: bytes, fragment: int = 16000, sop_class: str | None = XA_STORAGE) -> None:
    """A C-STORE-RQ of the encoded data set ``data`` in P-DATA-TF PDUs of ``fragment`` bytes."""
    sock.sendall(pdata(0x03, command_bytes(0x0001, sop_class, uid)))
    for at in range(0, len(data), fragment):
        sock.sendall(pdata(0x02 if at + fragment >= len(data) else 0x00, data[at:at + fragment]))


def elements(data: bytes) -> list[tuple[int, int, int]]:
    """The top-level elements of an explicit VR little endian data set: (tag, offset, header size)."""
    out, at = [], 0
    while at + 8 <= len(data):
        tag = int.from_bytes(data[at:at + 2], "little") << 16 | int.from_bytes(data[at + 2:at + 4], "little")
        long = data[at + 4:at + 6] in LONG_VRS
        header = 12 if long else 8
        length = int.from_bytes(data[at + 8:at + 12], "little") if long else \
            int.from_bytes(data[at + 6:at + 8], "little")
        out.append((tag, at, header))
        if length == 0xFFFFFFFF:  # a sequence of undefined length: up to its delimitation item
            end = data.find(b"\xfe\xff\xdd\xe0\x00\x00\x00\x00", at + header)
            at = len(data) if end < 0 else end + 8
        else:
            at += header + length
    return out


# --- the hostile associations: each ``kind(port, rng, views, limits) -> outcome`` --------------------

JPEG_LOSSLESS = "1.2.840.10008.1.2.4.70"


def hostile_object(views, rng):
    """A small XA object of plane A taken at :data:`HOSTILE_T0` plus up to an hour."""
    view = views[0]
    counts = rng.integers(100, 4000, size=view.shape).astype(np.uint16)
    return xa_dataset(view, counts, acquisition_time=HOSTILE_T0 + dt.timedelta(seconds=int(rng.integers(3600))),
                      uid_seed=f"hostile/{int(rng.integers(1 << 62))}")


def encoded(ds) -> bytes:
    from pynetdicom.dsutils import encode

    return encode(ds, False, True)


def store_object(port: int, data: bytes, uid: str, sop_class: str | None = XA_STORAGE,
                 syntax: str = EXPLICIT_LE) -> str:
    """A C-STORE of the encoded ``data`` in its own association: the receiver's answer."""
    with associated(port, XA_STORAGE, syntax) as sock:
        send_dataset(sock, uid, data, sop_class=sop_class)
        answer = reaction(sock)
        if answer.startswith("status"):
            sock.sendall(pdu(0x05, bytes(4)))
            reaction(sock)
    return answer


def random_bytes(port, rng, views, limits) -> str:
    """Up to 4 KiB of random bytes, then the end of what the client sends."""
    with connect(port) as sock:
        sock.sendall(rng.bytes(int(rng.integers(1, 4096))))
        sock.shutdown(socket.SHUT_WR)
        return reaction(sock)


def truncated_associate(port, rng, views, limits) -> str:
    """A valid A-ASSOCIATE-RQ cut at a random byte, then the end of what the client sends."""
    request = associate_rq()
    with connect(port) as sock:
        sock.sendall(request[:int(rng.integers(1, len(request)))])
        sock.shutdown(socket.SHUT_WR)
        return reaction(sock)


def wrong_pdu_type(port, rng, views, limits) -> str:
    """A PDU of an unknown type, or of one a connection cannot start with; the client then waits."""
    kind = int(rng.choice([0x00, 0x02, 0x03, 0x05, 0x06, 0x08, 0x10, 0x7F, 0xFF]))
    with connect(port) as sock:
        sock.sendall(pdu(kind, rng.bytes(int(rng.integers(0, 256)))))
        return reaction(sock)


def long_pdu_length(port, rng, views, limits) -> str:
    """A PDU whose length field exceeds what follows (0xFFFFFFFF, or up to 2 GiB), then the end."""
    body = rng.bytes(int(rng.integers(0, 65536)))
    length = 0xFFFFFFFF if rng.random() < 0.5 else int(rng.integers(len(body) + 1, 1 << 31))
    with connect(port) as sock:
        sock.sendall(pdu(int(rng.integers(1, 8)), body, length))
        sock.shutdown(socket.SHUT_WR)
        return reaction(sock)


def huge_pdu(port, rng, views, limits) -> str:
    """A PDU announcing more than the receiver reads, its body streamed (``limits.stream_bytes``):
    ``cut`` when the receiver closes the connection before the stream is sent."""
    chunk = rng.bytes(65536)
    with connect(port) as sock:
        sock.sendall(pdu(int(rng.choice([0x01, 0x04])), b"", int(rng.integers(limits.max_pdu_bytes + 1, 1 << 32))))
        for _ in range(limits.stream_bytes // len(chunk)):
            sock.sendall(chunk)
        sock.shutdown(socket.SHUT_WR)
        return "sent, " + reaction(sock)


def pdata_first(port, rng, views, limits) -> str:
    """A P-DATA-TF (a C-ECHO request) before any association; the client then waits."""
    with connect(port) as sock:
        sock.sendall(pdata(0x03, command_bytes(0x0030, VERIFICATION, has_data=False)))
        return reaction(sock)


def stalled_pdu(port, rng, views, limits) -> str:
    """Part of a PDU (an A-ASSOCIATE-RQ, or a data set's P-DATA-TF in an association), then
    silence: the receiver must close it after its network timeout."""
    if rng.random() < 0.5:
        sock = connect(port)
        part = associate_rq()
    else:
        sock = associated(port)
        sock.sendall(pdata(0x03, command_bytes(0x0001, XA_STORAGE, "1.2.3.4")))
        part = pdata(0x00, rng.bytes(4096))
    with sock:
        sock.sendall(part[:int(rng.integers(1, len(part)))])
        return reaction(sock)


def truncated_dataset(port, rng, views, limits) -> str:
    """A C-STORE whose data set is cut at a random byte."""
    ds = hostile_object(views, rng)
    data = encoded(ds)
    return store_object(port, data[:int(rng.integers(1, len(data)))], ds.SOPInstanceUID)


def wrong_vr(port, rng, views, limits) -> str:
    """A C-STORE whose data set has one to three elements' VRs replaced by random letters."""
    ds = hostile_object(views, rng)
    data = bytearray(encoded(ds))
    found = elements(bytes(data))
    for k in rng.choice(len(found), size=int(rng.integers(1, 4)), replace=False):
        at = found[k][1]
        data[at + 4:at + 6] = bytes(rng.integers(65, 91, size=2).astype(np.uint8))
    return store_object(port, bytes(data), ds.SOPInstanceUID)


def garbage_pixel_length(port, rng, views, limits) -> str:
    """A C-STORE whose PixelData length field is garbage: undefined, half, beyond the data, odd.
    Half is refused (0xA900: too few pixels, the rest read as garbled elements); a length beyond
    the data, the last element's, is read to the end by pydicom: the pixels whole, accepted."""
    ds = hostile_object(views, rng)
    data = bytearray(encoded(ds))
    at = next(offset for tag, offset, _ in elements(bytes(data)) if tag == 0x7FE00010)
    length = int.from_bytes(data[at + 8:at + 12], "little")
    data[at + 8:at + 12] = int(rng.choice([0xFFFFFFFF, length // 2, length + 2 * int(rng.integers(1, 1 << 20)),
                                           int(rng.integers(0, 1 << 31)) | 1])).to_bytes(4, "little")
    return store_object(port, bytes(data), ds.SOPInstanceUID)


def missing_sop_class(port, rng, views, limits) -> str:
    """A C-STORE without a SOP class: in the data set, or in the command."""
    ds = hostile_object(views, rng)
    if rng.random() < 0.5:
        del ds.SOPClassUID
        return store_object(port, encoded(ds), ds.SOPInstanceUID)
    return store_object(port, encoded(ds), ds.SOPInstanceUID, sop_class=None)


def huge_image(port, rng, views, limits) -> str:
    """A C-STORE declaring an enormous image: Rows and Columns up to 65535 over the same small
    pixel data, or (JPEG Lossless, where no length is implied) up to 2**30 frames in two fragments."""
    from pydicom.encaps import encapsulate

    from histostudy.imaging.io import RECEIVABLE_TRANSFER_SYNTAXES

    ds = hostile_object(views, rng)
    if rng.random() < 0.5 or JPEG_LOSSLESS not in RECEIVABLE_TRANSFER_SYNTAXES:
        ds.Rows, ds.Columns = int(rng.integers(1 << 15, 1 << 16)), int(rng.integers(1 << 15, 1 << 16))
        return store_object(port, encoded(ds), ds.SOPInstanceUID)
    ds.NumberOfFrames = int(rng.integers(1 << 20, 1 << 30))
    ds.PixelData = encapsulate([rng.bytes(64), rng.bytes(64)])
    ds["PixelData"].VR, ds["PixelData"].is_undefined_length = "OB", True
    ds.file_meta.TransferSyntaxUID = JPEG_LOSSLESS
    return store_object(port, encoded(ds), ds.SOPInstanceUID, syntax=JPEG_LOSSLESS)


def oversize_pixels(port, rng, views, limits) -> str:
    """A C-STORE whose PixelData is far larger than its image (two to four times the receiver's
    ``limits.max_object_bytes``), streamed in P-DATA-TF PDUs of the negotiated size: ``cut`` when
    the receiver closes the connection before the stream is sent."""
    ds = hostile_object(views, rng)
    del ds.PixelData
    size = int(rng.integers(2, 5)) * limits.max_object_bytes
    head = encoded(ds) + b"\xe0\x7f\x10\x00OW\x00\x00" + size.to_bytes(4, "little")
    chunk = rng.bytes(16000)
    with associated(port) as sock:
        sock.sendall(pdata(0x03, command_bytes(0x0001, XA_STORAGE, ds.SOPInstanceUID)) + pdata(0x00, head))
        for sent in range(0, size, len(chunk)):
            sock.sendall(pdata(0x02 if sent + len(chunk) >= size else 0x00, chunk[:size - sent]))
        return "sent, " + reaction(sock)


def dropped_mid_pdata(port, rng, views, limits) -> str:
    """A C-STORE of a valid object whose connection is dropped in the middle of a P-DATA-TF PDU
    (closed, or reset with SO_LINGER 0)."""
    ds = hostile_object(views, rng)
    data = encoded(ds)
    cut = int(rng.integers(1, len(data)))
    with associated(port) as sock:
        sock.sendall(pdata(0x03, command_bytes(0x0001, XA_STORAGE, ds.SOPInstanceUID)))
        sock.sendall(pdata(0x00, data[:cut]) + pdata(0x02, data[cut:])[:int(rng.integers(1, 7 + len(data) - cut))])
        if rng.random() < 0.5:  # closed with a reset (RST) rather than an orderly FIN
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    return "dropped"


#: The hostile kinds, by name (the fuzz draws among them).
HOSTILE = {f.__name__: f for f in (random_bytes, truncated_associate, wrong_pdu_type, long_pdu_length, huge_pdu,
                                   pdata_first, stalled_pdu, truncated_dataset, wrong_vr, garbage_pixel_length,
                                   missing_sop_class, huge_image, oversize_pixels, dropped_mid_pdata)}
#: The kinds whose object must be refused (a failure status) or whose association must be ended.
MUST_FAIL = {"truncated_dataset", "missing_sop_class", "huge_image"}
#: The kinds the receiver must cut off before the client is done (or end on its own, when stalled).
CUT_OFF = {"huge_pdu", "oversize_pixels", "stalled_pdu"}


def hostile(port: int, views, seed: int, index: int, limits, kinds=tuple(HOSTILE)) -> tuple[str, str]:
    """Hostile association ``index`` of the fuzz seeded ``seed``: ``(kind, outcome)``, its draws
    from ``numpy.random.default_rng([seed, index])`` (so one case replays alone). An OSError while
    the client sends is ``cut`` (the receiver closed the connection); any other error is
    ``error: ...`` (a fault of the fuzz, or of the receiver's answers)."""
    rng = np.random.default_rng([seed, index])
    kind = kinds[int(rng.integers(len(kinds)))]
    try:
        return kind, HOSTILE[kind](port, rng, views, limits)
    except TimeoutError:
        return kind, "timeout"
    except OSError:
        return kind, "cut"
    except Exception as exc:
        return kind, f"error: {type(exc).__name__}: {exc}"


def acceptable(kind: str, outcome: str) -> bool:
    """Whether the receiver's answer to a hostile association of ``kind`` is one it may give: never
    silence (``timeout``) nor a handler's exception (``status 0xC211``); a failure status or the
    association ended for :data:`MUST_FAIL`; cut off, or ended without an answer, for :data:`CUT_OFF`."""
    if outcome in ("timeout", "status 0xC211") or outcome.startswith("error"):
        return False
    if kind in MUST_FAIL:
        return outcome != "status 0x0000"
    if kind in CUT_OFF:
        return outcome in ("cut", "closed", "reset", "aborted") or (kind == "oversize_pixels" and outcome in (
            "sent, closed", "sent, reset", "sent, aborted"))
    return True


def rss_bytes() -> int | None:
    """This process's resident memory (``VmRSS`` of /proc/self/status; None without one)."""
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmRSS:"))
    except (OSError, StopIteration):
        return None


def send_good(objects, port: int, timeout_s: float, resent: list) -> list[int]:
    """:func:`histostudy.lab.send_frames` of a legitimate sender, tried again while the receiver
    rejects it transiently (its limit of associations at once, held by hostile ones), and sent again
    (appended to ``resent``) when its association was aborted: its sender starved of the CPU past
    the receiver's network timeout, as a C-arm's store queue would."""
    from histostudy.lab import send_frames

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return send_frames(objects, "127.0.0.1", port, calling_ae_title="GOOD", timeout_s=timeout_s)
        except ConnectionError as exc:
            if time.monotonic() > deadline or not ("A-ASSOCIATE-RJ result 2" in str(exc) or "aborted" in str(exc)):
                raise
            if "aborted" in str(exc):
                resent.append(str(exc))
            time.sleep(0.2)


def _settled(timeout_s: float) -> bool:
    """Wait until no association of pynetdicom's runs (its threads, ``AcceptorThread@...``, end
    within the receiver's network timeout of their last read) and no connection is still being
    admitted (the server's ``process_request_thread`` threads, lab.admitting_server, which may
    yet start an association): whether none does."""
    deadline = time.monotonic() + timeout_s
    while any(t.name.startswith("AcceptorThread") or "process_request_thread" in t.name
              for t in threading.enumerate()):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def run_fuzz(receiver, views, *, seed: int, n_hostile: int, concurrency: int, good_per_batch: int = 1,
             kinds=tuple(HOSTILE), stream_bytes: int = 16 << 20, measure=None, timeout_s: float = 60.0) -> dict:
    """``n_hostile`` hostile associations (:func:`hostile`, ``seed``) against a started ``receiver``
    (``max_queued_pairs=None``), ``concurrency`` at once; beside each batch a legitimate sender
    stores ``good_per_batch`` good pairs, one after the other (:func:`pair_objects`,
    :func:`histostudy.lab.send_frames`), and after it the receiver must answer a C-ECHO and have
    posed them. ``measure()`` (e.g. :func:`rss_bytes`)
    is taken after the first batch and at the end, each once no association runs any more.

    Returns ``kinds`` (hostile associations per kind), ``outcomes`` (per kind, per outcome),
    ``failures`` (``(index, kind, outcome)`` not :func:`acceptable`: replay with :func:`hostile`),
    ``crashes`` (failed C-ECHOs, good pairs refused or not posed, exceptions that ended a thread,
    handlers' exceptions), ``good_sent``, ``good_posed``, ``good_uids`` (per pair), ``good_resent``
    (why each pair sent again: :func:`send_good`), ``memory``
    (``after_first``, ``after_all``, and ``settled``: whether no association ran at either) and
    ``seconds``.
    """
    limits = SimpleNamespace(max_pdu_bytes=receiver.max_pdu_bytes, max_object_bytes=receiver.max_object_bytes,
                             stream_bytes=stream_bytes)
    outcomes, failures, good_uids, memory, resent = collections.defaultdict(collections.Counter), [], [], {}, []
    crashes, thread_errors, hook = collections.Counter(), [], threading.excepthook
    threading.excepthook = lambda args: (thread_errors.append(args.exc_type.__name__), hook(args))
    t0 = time.perf_counter()
    try:
        with ThreadPoolExecutor(concurrency, thread_name_prefix="fuzz-client") as pool:
            for batch, start in enumerate(range(0, n_hostile, concurrency)):
                futures = [(i, pool.submit(hostile, receiver.port, views, seed, i, limits, kinds))
                           for i in range(start, min(start + concurrency, n_hostile))]
                for _ in range(good_per_batch):
                    objects = pair_objects(views, len(good_uids))
                    good_uids.append([ds.SOPInstanceUID for ds in objects])
                    crashes["good_refused"] += send_good(objects, receiver.port, timeout_s, resent) != [0, 0]
                for i, future in futures:
                    kind, outcome = future.result()
                    outcomes[kind][outcome] += 1
                    crashes["handler_exceptions"] += outcome == "status 0xC211"
                    if not acceptable(kind, outcome):
                        failures.append((i, kind, outcome))
                crashes["echo_failed"] += echo(receiver.port) != "status 0x0000"
                crashes["good_not_posed"] += not receiver.wait_for_pairs(len(good_uids), timeout_s)
                if measure is not None and batch == 0:
                    memory["settled"] = _settled(timeout_s)
                    memory["after_first"] = measure()
    finally:
        threading.excepthook = hook
    if measure is not None:
        memory["settled"] = _settled(timeout_s) and memory.get("settled", True)
        memory["after_all"] = measure()
    crashes["thread_exceptions"] = len(thread_errors)
    return {"kinds": {k: sum(v.values()) for k, v in sorted(outcomes.items())},
            "outcomes": {k: dict(v) for k, v in sorted(outcomes.items())}, "failures": failures,
            "crashes": sum(crashes.values()), "crash_kinds": dict(crashes), "good_sent": len(good_uids),
            "good_posed": receiver.stats()["pairs_processed"], "good_uids": good_uids, "good_resent": resent,
            "memory": memory,
            "seconds": time.perf_counter() - t0}


# --- a whole procedure (tests/lab/test_receiver_soak.py, benchmarks/bench_receiver_soak.py) --------

SOAK_T0 = dt.datetime(2026, 11, 28, 9, 0, 0)
#: The hostile kinds mixed into a soak: all but a stalled PDU (it holds its connection for the
#: network timeout) and an oversize object (it streams gigabytes at the receiver's data set bound).
SOAK_KINDS = tuple(k for k in HOSTILE if k not in ("stalled_pdu", "oversize_pixels"))


def cine_pair(views, k: int, fps: float, rng) -> list:
    """Plane A's and B's frame ``k`` of a cine at ``fps``: two single-frame XA objects."""
    when = SOAK_T0 + dt.timedelta(seconds=k / fps)
    return [xa_dataset(v, rng.integers(100, 4000, size=v.shape).astype(np.uint16), acquisition_time=when,
                       uid_seed=f"soak/{k}/{v.name}") for v in views]


def _send_cine(port: int, views, fps: float, resend_every: int, drop_every: int, seed: int,
               stop: threading.Event, sent: dict) -> None:
    """The C-arm of a soak: one association, each pair at its time, every ``resend_every``-th stored
    twice (a response lost), every ``drop_every``-th after a connection dropped mid-object."""
    from pynetdicom import AE

    rng = np.random.default_rng(seed)
    ae = AE(ae_title="CARM")
    ae.add_requested_context(XA_STORAGE, EXPLICIT_LE)
    assoc = ae.associate("127.0.0.1", port, ae_title="HISTOSTUDY")
    t_start, k = time.monotonic(), 0
    try:
        while not stop.is_set() and assoc.is_established:
            wait = t_start + k / fps - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            if drop_every and k % drop_every == drop_every - 1:
                try:
                    dropped_mid_pdata(port, rng, views, None)
                except OSError:
                    pass
                sent["dropped"] += 1
            objects = cine_pair(views, k, fps, rng)
            times = 2 if resend_every and k % resend_every == resend_every - 1 else 1
            for _ in range(times):
                for ds in objects:
                    sent["statuses"][int(getattr(assoc.send_c_store(ds), "Status", -1))] += 1
            sent["frames"] += 2
            sent["resent"] += 2 * (times - 1)
            sent["uids"].append([ds.SOPInstanceUID for ds in objects])
            k += 1
    finally:
        if assoc.is_established:
            assoc.release()


def _send_hostile(receiver, views, per_min: float, seed: int, stop: threading.Event, outcomes) -> None:
    """Hostile associations at random times, ``per_min`` a minute on average."""
    rng = np.random.default_rng(seed + 1)
    limits = SimpleNamespace(max_pdu_bytes=receiver.max_pdu_bytes, max_object_bytes=receiver.max_object_bytes,
                             stream_bytes=1 << 20)
    index = 0
    while per_min > 0 and not stop.wait(rng.exponential(60.0 / per_min)):
        kind, outcome = hostile(receiver.port, views, seed, index, limits, kinds=SOAK_KINDS)
        outcomes[(kind, outcome)] += 1
        index += 1


def run_soak(receiver, views, *, seconds: float, fps: float = 15.0, resend_every: int = 50, drop_every: int = 100,
             hostile_per_min: float = 30.0, seed: int = 20261128, sample_s: float = 5.0) -> dict:
    """A started live ``receiver`` fed one C-arm's paced biplane cine for ``seconds`` (frame ``k`` of
    each plane at ``k / fps`` s), with pairs stored twice, drops mid-object and hostile peers; its
    counts, RSS and threads sampled every ``sample_s``. Returns ``sent`` (frames, resent, dropped,
    the C-arm's statuses, its pairs' UIDs), ``hostile`` (per (kind, outcome)), ``samples``
    (``t_s``, ``rss``, ``threads``, ``p99_s``), ``stats`` and ``threads_end``."""
    sent = {"frames": 0, "resent": 0, "dropped": 0, "statuses": collections.Counter(), "uids": []}
    outcomes: collections.Counter = collections.Counter()
    samples = []
    stop = threading.Event()
    workers = [threading.Thread(target=_send_cine, args=(receiver.port, views, fps, resend_every, drop_every, seed,
                                                         stop, sent)),
               threading.Thread(target=_send_hostile, args=(receiver, views, hostile_per_min, seed, stop, outcomes))]
    t0 = time.monotonic()
    for w in workers:
        w.start()
    try:
        while time.monotonic() - t0 < seconds:
            time.sleep(min(sample_s, max(0.0, seconds - (time.monotonic() - t0))))
            stats = receiver.stats()
            samples.append({"t_s": time.monotonic() - t0, "rss": rss_bytes(), "threads": len(threading.enumerate()),
                            "p99_s": stats["latency_s"]["p99"]})
    finally:
        stop.set()
        for w in workers:
            w.join(60)
    _settled(30.0)
    return {"sent": sent, "hostile": dict(outcomes), "samples": samples, "stats": receiver.stats(),
            "threads_end": len(threading.enumerate())}
