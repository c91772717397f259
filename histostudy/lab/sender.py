"""X-ray objects sent to a DICOM Storage SCP (C-STORE), the C-arm's end of the cable (§II-A): for
tests, demonstrations and replaying a lab's recorded cines to the receiver, at once
(:func:`send_frames`) or at the pace of the acquisition (:func:`stream_frames`; docs/receiver.md,
"The sender").
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from histostudy.core.checks import check_ae_title, check_host, check_port, check_positive

__all__ = ["SentObject", "send_frames", "stream_frames"]


@dataclass(frozen=True)
class SentObject:
    """One object :func:`stream_frames` stored, and when.

    Args:
        index: its position in the input.
        status: the receiver's C-STORE status (0x0000 success).
        due_s: when its last frame was taken (s from the first object's first frame, over the pace).
        sent_s: when its C-STORE request went out (s from the start of the sending).
        answered_s: when its response came back (s from the start of the sending).

    ``late_s`` (property) is ``sent_s - due_s``: > 0 where the sender fell behind the C-arm.
    """

    index: int
    status: int
    due_s: float
    sent_s: float
    answered_s: float

    @property
    def late_s(self) -> float:
        return self.sent_s - self.due_s


def send_frames(paths: Sequence, host: str, port: int, *, ae_title: str = "HISTOSTUDY",
                calling_ae_title: str = "HISTOSTUDY_SCU", timeout_s: float = 30.0, tls=None) -> list[int]:
    """Store DICOM objects on a Storage SCP in one association; the C-STORE status of each, in order.

    Args:
        paths: the objects: DICOM files (paths) or pydicom ``Dataset`` objects with their
            ``file_meta`` (its ``TransferSyntaxUID``), sent in this order.
        host, port: the SCP's address and TCP port (1..65535).
        ae_title: the SCP's AE title (the "called AE title"; the receiver's default
            ``HISTOSTUDY``).
        calling_ae_title: this sender's AE title.
        timeout_s: seconds to wait for the association and for each response.
        tls: None (plain TCP), a :class:`~.tls.TLSConfig` (``ca``: the CA that signed the
            receiver's certificate, None: the system's; ``cert``/``key``: this sender's, for a
            receiver that asks for one) or a client-side ``ssl.SSLContext``. The receiver's
            certificate must name ``host``.

    Returns:
        The C-STORE response status per object (an int: 0x0000 success, else the SCP's failure
        or warning status).

    Raises:
        FileNotFoundError: a path that does not exist (before anything is sent).
        ValueError: an object that is not DICOM, lacks its SOP class or transfer syntax, or a bad
            argument (naming it).
        ConnectionError: the SCP unreachable, the TLS handshake failed, the association rejected
            (with the A-ASSOCIATE-RJ reason) or aborted, or no response to an object (naming the
            object and what was stored before it).
    """
    return [sent.status for sent in _store(paths, host, port, ae_title=ae_title, calling_ae_title=calling_ae_title,
                                           timeout_s=timeout_s, pace=None, tls=tls)]


def stream_frames(paths: Sequence, host: str, port: int, *, pace: float = 1.0, ae_title: str = "HISTOSTUDY",
                  calling_ae_title: str = "HISTOSTUDY_SCU", timeout_s: float = 30.0, tls=None) -> list[SentObject]:
    """:func:`send_frames` at the pace of the acquisition, as a C-arm streams a fluoroscopy run.

    Each object is stored no earlier than its last frame's acquisition time
    (:func:`.pairing.frame_times`) after the first object's first frame, divided by ``pace``. An
    object whose time has passed (the receiver answered the one before late) goes at once: the
    sender never skips. Objects given as paths are read when they are stored.

    Args:
        paths: the objects in acquisition order (e.g. plane A's frame k, plane B's frame k, then
            frame k + 1): file paths or pydicom Datasets.
        host: the receiver's host name or address.
        port: its TCP port (1-65535).
        pace: the speed-up (1.0: real time; 2.0: twice as fast); a finite number > 0.
        ae_title: the receiver's AE title (the called one).
        calling_ae_title: this sender's AE title.
        timeout_s: the association's network timeout (s).
        tls: None (plain TCP) or a :class:`~.tls.TLSConfig` (or a client-side ``ssl.SSLContext``).

    Returns:
        One :class:`SentObject` per object, in order.

    Raises:
        ValueError: an object without an acquisition time (named), a ``pace`` that is not a finite
            number > 0, or what :func:`send_frames` refuses.
        ConnectionError: as :func:`send_frames`.
    """
    check_positive(pace, "pace", what="a finite speed-up > 0 (1.0: the acquisition's own pace)")
    return _store(paths, host, port, ae_title=ae_title, calling_ae_title=calling_ae_title, timeout_s=timeout_s,
                  pace=float(pace), tls=tls)


def _read(items: list) -> tuple[list, list[str]]:
    """Each object's dataset (a path: its header only, the pixels read when it is stored) and name,
    checked as :func:`send_frames` says."""
    import pydicom
    from pydicom.dataset import Dataset
    from pydicom.errors import InvalidDicomError

    headers, names = [], []
    for i, item in enumerate(items):
        if isinstance(item, Dataset):
            ds, name = item, f"paths[{i}] (SOPInstanceUID {getattr(item, 'SOPInstanceUID', '?')})"
        elif isinstance(item, (str, os.PathLike)):
            name = f"file {str(item)!r}"
            if not Path(item).is_file():
                raise FileNotFoundError(f"{name}: no such file")
            try:
                ds = pydicom.dcmread(item, stop_before_pixels=True)
            except (InvalidDicomError, OSError, ValueError) as exc:
                raise ValueError(f"{name} is not a readable DICOM file: {exc}") from None
        else:
            raise ValueError(f"paths[{i}] must be a file path or a pydicom Dataset, got {type(item).__name__}")
        syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
        if not getattr(ds, "SOPClassUID", None) or syntax is None:
            raise ValueError(f"{name} lacks its SOPClassUID (0008,0016) or its file meta TransferSyntaxUID "
                             "(0002,0010): a C-STORE needs both")
        headers.append(ds)
        names.append(name)
    return headers, names


def _due_s(headers: list, names: list[str], pace: float) -> list[float]:
    """When each object may go (s from the first object's first frame, over ``pace``): its last frame's time."""
    from .pairing import frame_times, posix_seconds

    last = []
    for ds, name in zip(headers, names):
        try:
            times, _ = frame_times(ds)
        except ValueError as exc:
            raise ValueError(f"{name} cannot be paced: {exc}") from None
        last.append((posix_seconds(times[0]), posix_seconds(times[-1])))
    first = last[0][0]
    return [(end - first) / pace for _, end in last]


def _store(paths, host: str, port: int, *, ae_title: str, calling_ae_title: str, timeout_s: float,
           pace: float | None, tls=None) -> list[SentObject]:
    """Store the objects in one association (at ``pace``, or at once with None); a SentObject each."""
    import pydicom
    from pydicom.dataset import Dataset
    from pydicom.uid import UID, ExplicitVRLittleEndian, ImplicitVRLittleEndian
    from pynetdicom import AE, evt

    from .tls import tls_context

    if isinstance(paths, (str, os.PathLike, Dataset)):
        paths = [paths]
    items = list(paths)
    if not items:
        raise ValueError("paths must name at least one DICOM object, got none")
    host, port = check_host(host), check_port(port, allow_zero=False)
    ae_title, calling_ae_title = check_ae_title(ae_title), check_ae_title(calling_ae_title, "calling_ae_title")
    check_positive(timeout_s, "timeout_s", what="a finite number of seconds > 0")
    context = tls_context(tls, server=False)
    headers, names = _read(items)
    due = [0.0] * len(items) if pace is None else _due_s(headers, names, pace)

    ae = AE(ae_title=calling_ae_title)
    ae.acse_timeout = ae.dimse_timeout = ae.network_timeout = float(timeout_s)
    # a compressed syntax in a context of its own: pynetdicom sends such an object only as it is, and
    # an SCP offered it beside the native ones may choose a native one (the receiver does)
    contexts: dict[tuple[str, str], list[str]] = {}
    for ds in headers:
        syntax = UID(str(ds.file_meta.TransferSyntaxUID))
        syntaxes = contexts.setdefault((str(ds.SOPClassUID), syntax if syntax.is_compressed else ""), [])
        for uid in (syntax,) if syntax.is_compressed else (syntax, ExplicitVRLittleEndian, ImplicitVRLittleEndian):
            if uid not in syntaxes:
                syntaxes.append(uid)
    for (sop_class, _), syntaxes in contexts.items():
        ae.add_requested_context(sop_class, syntaxes)
    where = f"{ae_title}@{host}:{port}" + (" over TLS" if context is not None else "")
    connected: list[object] = []  # the TCP connection opened: a failed association is then the peer's answer
    assoc = ae.associate(host, port, ae_title=ae_title, evt_handlers=[(evt.EVT_CONN_OPEN, connected.append)],
                         tls_args=None if context is None else (context, host))
    if not assoc.is_established:
        raise ConnectionError(f"the DICOM Storage SCP {where} {_refusal(assoc, bool(connected), context is not None)}")
    sent: list[SentObject] = []
    t0 = time.perf_counter()
    try:
        for i, (item, name) in enumerate(zip(items, names)):
            ds = item if isinstance(item, Dataset) else pydicom.dcmread(item)
            wait = due[i] - (time.perf_counter() - t0)
            if wait > 0:
                time.sleep(wait)
            t_sent = time.perf_counter() - t0
            try:
                response = assoc.send_c_store(ds)
            except ValueError as exc:  # pynetdicom: no accepted presentation context for its class
                raise ConnectionError(f"{where} accepted no presentation context for {name}: {exc}") from None
            if "Status" not in response:
                raise ConnectionError(f"{where} sent no C-STORE response to {name} (after {len(sent)} "
                                      "object(s) stored): the association was aborted or timed out")
            sent.append(SentObject(i, int(response.Status), due[i], t_sent, time.perf_counter() - t0))
    finally:
        if assoc.is_established:
            assoc.release()
    return sent


def _refusal(assoc, connected: bool, tls: bool) -> str:
    """What a failed association request says: unreachable, rejected (with the A-ASSOCIATE-RJ's
    result, source and reason), or aborted."""
    if not connected:
        return ("could not be reached or refused the TLS handshake (is it listening there, over TLS, with a "
                "certificate the given CA signed for that address?)" if tls else
                "could not be reached (is it listening there?)")
    if assoc.is_rejected:
        answer = assoc.acceptor.primitive
        reason = getattr(answer, "diagnostic", None)
        # keyed by object: the answer may carry no diagnostic (None), which names no known reason
        known: dict[object, str] = {3: ": calling AE title not recognised", 7: ": called AE title not recognised"}
        return (f"rejected the association (A-ASSOCIATE-RJ result {getattr(answer, 'result', '?')}, source "
                f"{getattr(answer, 'result_source', '?')}, reason {reason}" + known.get(reason, "") + ")")
    return ("aborted the association request" +
            (" (over TLS: did it refuse this sender's certificate?)" if tls else ""))
