"""Who may send frames to the live receiver, and where it listens (§II-A): the allow-list of
modalities (:class:`AllowList`, :func:`load_modalities`, :func:`parse_allow`) checked on a new
connection's first bytes and at association negotiation (:class:`AssociationGate`), the bounds of
every connection (:class:`ConnectionGuard`) and the listening address tried before anything is
written (docs/receiver.md, "Who may send").
"""

from __future__ import annotations

import dataclasses
import errno
import ipaddress
import json
import logging
import os
import select
import socket
import ssl
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

from histostudy.core.checks import check_ae_title, check_host, check_port

__all__ = ["AllowList", "AssociationGate", "Modality", "check_listening_address", "load_modalities",
           "parse_allow"]

log = logging.getLogger("histostudy.lab.receiver")  # the receiver's log, where its users look

#: A-ASSOCIATE-RJ reasons (source 1, DICOM UL service user; PS3.8 §9.3.4) the gate answers with.
REJECT_REASONS = {1: "no reason given", 3: "calling AE title not recognised", 7: "called AE title not recognised"}
#: The largest P-DATA PDU the receiver announces to its senders (bytes; the maximum length of its
#: A-ASSOCIATE-AC, :func:`.xray_objects.storage_application_entity`): a frame in a few PDUs rather than
#: pynetdicom's default of 16 KiB each, since every PDU is parsed in Python on both sides.
RECEIVER_MAX_PDU_BYTES = 1 << 20
#: The largest PDU a connection may announce (bytes; :class:`ConnectionGuard`): 4 times the 1 MiB the
#: receiver announces (:data:`RECEIVER_MAX_PDU_BYTES`), room for a sender that overshoots it, and ample
#: for an A-ASSOCIATE-RQ proposing every storage class, which no announced maximum bounds.
MAX_PDU_BYTES = 4 * RECEIVER_MAX_PDU_BYTES
#: The largest data set one message may bring (bytes): a cine of 500 frames of 1024 x 1024 at 16 bits.
MAX_OBJECT_BYTES = 1 << 30
#: The most bytes of data sets all connections together may hold while they are being received
#: (:class:`ConnectionGuard`): two objects at :data:`MAX_OBJECT_BYTES`, so that ten senders at once
#: cannot hold ten times that.
MAX_IN_FLIGHT_BYTES = 2 * MAX_OBJECT_BYTES
#: How many associations, negotiated, senders off the allow-list (or every sender, without one) may
#: hold at once (:class:`AssociationGate`): pynetdicom's own default. An allow-listed sender is
#: never turned away for them; connections that have not negotiated are not counted.
MAX_ASSOCIATIONS = 10
#: How long a new connection may stay silent before its first bytes (seconds; :class:`ConnectionGuard`):
#: a DICOM sender sends its A-ASSOCIATE-RQ (or TLS ClientHello) as soon as it connects, a port scanner
#: or an idle peer sends nothing. Waited for on the connection's own thread, without polling, before
#: pynetdicom starts the association's threads (each polls every millisecond, and a hundred of them
#: take the C-arm's share of the GIL); a silent peer is closed then and never holds an association.
FIRST_BYTES_WAIT_S = 2.0
#: The fixed part of an A-ASSOCIATE-RQ, up to its calling AE title (PS3.8 Table 9-11: bytes 11-26 the
#: called, 27-42 the calling AE title).
_RQ_HEAD_BYTES = 42
#: The most connections the receiver serves at once (each a thread): pynetdicom's own limit is set
#: this high so that it counts only what the gate does not.
MAX_CONNECTIONS = 256


def _address(value: str, name: str) -> str:
    """An IP address in its canonical text (an IPv4-mapped IPv6 address as the IPv4 one)."""
    try:
        address = ipaddress.ip_address(str(value).split("%")[0].strip())
    except ValueError:
        raise ValueError(f"{name} must be an IP address (e.g. '192.168.10.21' or '::1'; a host name is not "
                         f"resolved), got {value!r}") from None
    mapped = getattr(address, "ipv4_mapped", None)
    return str(mapped or address)


@dataclasses.dataclass(frozen=True)
class Modality:
    """One sender allowed to send frames to the receiver.

    Args:
        name: its name (the allow-list's key, for the log); a non-empty string.
        ae_title: the calling AE title it sends as, 1-16 ASCII characters (stripped).
        host: the IP address it must call from (an address, not a host name; an IPv4-mapped IPv6
            address is kept as IPv4), or None: any address.

    Raises:
        ValueError: an empty ``name``, an AE title that is not one, or a ``host`` that is not an IP
            address (the message names the modality).
    """

    name: str
    ae_title: str
    host: str | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"a modality's name must be a non-empty string, got {self.name!r}")
        object.__setattr__(self, "ae_title", check_ae_title(self.ae_title, f"modality {self.name!r} ae_title"))
        if self.host is not None:
            object.__setattr__(self, "host", _address(self.host, f"modality {self.name!r} host"))

    def allows(self, ae_title: str, address: str) -> bool:
        """Whether a peer calling as ``ae_title`` from ``address`` is this modality."""
        return ae_title.strip() == self.ae_title and (self.host is None or _peer(address) == self.host)

    def __str__(self) -> str:
        return self.ae_title + ("" if self.host is None else f"@{self.host}")


def peer_text(address) -> str:
    """A peer's ``(host, port, ...)`` socket address as ``"host:port"`` (for the log and records)."""
    return ":".join(str(part) for part in address[:2])


def _peer(address: str) -> str | None:
    try:
        return _address(address, "address")
    except ValueError:
        return None


@dataclasses.dataclass(frozen=True)
class AllowList:
    """The modalities allowed to send: a peer may send when one of them :meth:`Modality.allows` it.

    Args:
        modalities: one :class:`Modality` or several (kept as a tuple); at least one.

    Raises:
        ValueError: no modality, or an item that is not a Modality.
    """

    modalities: tuple[Modality, ...]

    def __post_init__(self):
        items = tuple(self.modalities) if not isinstance(self.modalities, Modality) else (self.modalities,)
        if not items or not all(isinstance(m, Modality) for m in items):
            raise ValueError(f"modalities must be one or more histostudy.lab.Modality, got {self.modalities!r}")
        object.__setattr__(self, "modalities", items)

    @property
    def ae_titles(self) -> list[str]:
        """The calling AE titles listed, sorted, each once."""
        return sorted({m.ae_title for m in self.modalities})

    def allows(self, ae_title: str, address: str) -> bool:
        return any(m.allows(ae_title, address) for m in self.modalities)

    def why_not(self, ae_title: str, address: str) -> str:
        """Why a peer is not allowed (for the log): its title unknown, or the addresses its title may call from."""
        hosts = [m.host for m in self.modalities if m.ae_title == ae_title.strip()]
        if not hosts:
            return f"the calling AE title {ae_title!r} is none of {self.ae_titles}"
        # a modality of that title without a host (None) would have allowed the peer: only addresses are left
        return f"{ae_title!r} may call only from {sorted({h for h in hosts if h is not None})}, not from {address}"

    def __add__(self, other: AllowList) -> AllowList:
        return AllowList(self.modalities + other.modalities)

    @classmethod
    def of(cls, allow) -> AllowList | None:
        """An AllowList from any of the forms the receiver's ``allow`` takes.

        Args:
            allow: an AllowList (returned as is), a :class:`Modality`, an ``"AE[@IP]"`` text
                (:func:`parse_allow`), an iterable of Modalities and texts, or None.

        Returns:
            The AllowList; None where ``allow`` is None (no list: any calling AE title may send).

        Raises:
            ValueError: an empty iterable, or an item of another kind.
        """
        if allow is None or isinstance(allow, AllowList):
            return allow
        items = [allow] if isinstance(allow, (Modality, str)) else list(allow) if isinstance(allow, Iterable) else None
        if not items or not all(isinstance(m, (Modality, str)) for m in items):
            raise ValueError("allow must be None, an AllowList, or Modality objects and 'AE[@HOST]' texts, got "
                             f"{allow!r}")
        return cls(tuple(m if isinstance(m, Modality) else parse_allow(m) for m in items))


def parse_allow(text: str) -> Modality:
    """A :class:`Modality` from its ``AE[@IP]`` text (``histostudy listen --allow``), named after it.

    Args:
        text: ``"AE"`` (any address) or ``"AE@IP"`` (an IP address, not a host name).

    Returns:
        The modality.

    Raises:
        ValueError: an empty text, an AE title that is not one, or a host that is not an IP address.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"allow must be 'AE_TITLE' or 'AE_TITLE@IP_ADDRESS', got {text!r}")
    title, _, host = text.strip().rpartition("@") if "@" in text else (text.strip(), "", "")
    return Modality(text.strip(), title, host or None)


def load_modalities(path: str | os.PathLike) -> AllowList:
    """The :class:`AllowList` of a JSON file, as Orthanc's ``DicomModalities``.

    The file holds ``{"modalities": {name: {"ae_title": ..., "host": ...}, ...}}``; ``host`` is
    optional, and ``port`` (the modality's own SCP port in Orthanc's lists) is accepted and not used:
    the receiver never calls back.

    Args:
        path: the JSON file.

    Returns:
        The allow-list, one :class:`Modality` per entry.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not JSON, not that shape, or an entry with a bad AE title, host or port (the
            message names the file and the entry).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"modalities file {str(path)!r}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"modalities file {str(path)!r} is not JSON: {exc}") from None
    entries = data.get("modalities") if isinstance(data, dict) else None
    if not isinstance(entries, dict) or not entries:
        raise ValueError(f"modalities file {str(path)!r} must hold {{\"modalities\": {{name: {{\"ae_title\": ..., "
                         f"\"host\": ...}}, ...}}}} with at least one modality, got {data!r}")
    modalities = []
    for name, entry in entries.items():
        where = f"modalities file {str(path)!r}, modality {name!r}"
        if not isinstance(entry, dict) or "ae_title" not in entry or set(entry) - {"ae_title", "host", "port"}:
            raise ValueError(f"{where} must be {{\"ae_title\": ..., \"host\": ... (optional), \"port\": ... "
                             f"(optional, unused)}}, got {entry!r}")
        try:
            if "port" in entry:
                check_port(entry["port"], "port", allow_zero=False)
            modalities.append(Modality(name, entry["ae_title"], entry.get("host")))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    return AllowList(tuple(modalities))


class AssociationGate:
    """The receiver's checks at association negotiation (module docstring): :meth:`configure` sets
    pynetdicom's own AE-title checks on the AE, :meth:`handlers` the address check and the log.

    ``on_rejected(record)`` is called once per rejected association with a dict: ``peer``
    (``"address:port"``), ``calling_ae_title``, ``called_ae_title``, ``reason`` (A-ASSOCIATE-RJ
    reason code) and ``why`` (text).
    """

    def __init__(self, allow: AllowList | None, on_rejected: Callable[[dict], object],
                 max_associations: int = MAX_ASSOCIATIONS):
        self.allow, self.on_rejected, self.max_associations = allow, on_rejected, int(max_associations)

    def configure(self, ae) -> None:
        """Make ``ae`` refuse another called AE title and, with a list, the titles not on it; its own
        limit of associations at once becomes :data:`MAX_CONNECTIONS` (the gate counts instead)."""
        ae.maximum_associations = MAX_CONNECTIONS
        ae.require_called_aet = True
        if self.allow is not None:
            ae.require_calling_aet = self.allow.ae_titles
        else:
            log.warning("no allow-list of modalities: any calling AE title, from any address that reaches "
                        "the receiver, may send frames (only the called AE title %r is checked)", ae.ae_title)

    def handlers(self) -> list:
        from pynetdicom import evt

        return [(evt.EVT_REQUESTED, self._on_requested), (evt.EVT_REJECTED, self._on_rejected)]

    def _on_requested(self, event) -> None:
        """A listed calling AE title from an address its modality may not call from: rejected (reason
        3); a sender off the list (any, without one) while :attr:`max_associations` are negotiated:
        rejected as transient (result 2, reason 2: local limit exceeded, to be tried again). The
        other checks are pynetdicom's, during the negotiation that follows."""
        assoc = event.assoc
        try:
            request = assoc.requestor.primitive
            calling, address = str(request.calling_ae_title).strip(), str(assoc.requestor.address)
            listed = self.allow is not None and self.allow.allows(calling, address)
            refused = self.allow is not None and calling in self.allow.ae_titles and not listed
            busy = not listed and sum(1 for other in assoc.ae.active_associations
                                      if other is not assoc and other.is_acceptor and other.is_established
                                      ) >= self.max_associations
        except Exception:  # a check that cannot be made refuses: the gate fails closed
            log.exception("the association's address check failed; rejecting it")
            refused, busy = True, False
        if refused:
            self._reject(assoc, 3)
        elif busy:
            self._reject(assoc, 2, result=2, source=3)

    @staticmethod
    def _reject(assoc, reason: int, result: int = 1, source: int = 1) -> None:
        """Reject (permanently: result 1, source 1, DICOM UL service-user; or transiently: result 2,
        source 3, service-provider presentation) with ``reason``, as pynetdicom's negotiation does."""
        from pynetdicom import evt

        assoc.acse.send_reject(result, source, reason)
        evt.trigger(assoc, evt.EVT_REJECTED, {})
        assoc.kill()

    def screen(self, sock, client_address, own_ae_title: str) -> bool:
        """Whether a new connection may go on to negotiate, judged on its first bytes
        (:class:`.admitting_server.AdmittingServer`, after :meth:`ConnectionGuard.await_first_bytes`):
        with an allow-list, an A-ASSOCIATE-RQ whose calling AE title and address the list does not
        allow is answered A-ASSOCIATE-RJ (reason 3) and closed before pynetdicom makes an association
        of it, so that strangers asking again and again cost one thread each, not three polling
        ones. A request not yet whole in its fixed part, and a TLS connection (its bytes cannot be
        peeked), go on to be checked at negotiation (:meth:`_on_requested`)."""
        from pynetdicom.pdu import A_ASSOCIATE_RJ

        if self.allow is None or isinstance(sock, ssl.SSLSocket):
            return True
        try:
            head = sock.recv(_RQ_HEAD_BYTES, socket.MSG_PEEK | socket.MSG_DONTWAIT)
        except OSError:  # nothing there, or closed meanwhile: pynetdicom finds out
            return True
        if len(head) < _RQ_HEAD_BYTES or head[0] != 0x01:
            return True
        calling, called = (head[at:at + 16].decode("ascii", "replace").strip() for at in (26, 10))
        address = str(client_address[0])
        try:
            if self.allow.allows(calling, address):
                return True
        except Exception:  # fails closed at negotiation instead, where it is logged
            return True
        reject = A_ASSOCIATE_RJ()
        reject.result, reject.source, reject.reason_diagnostic = 1, 1, 3
        try:
            sock.sendall(reject.encode())
            # the request read, so that closing sends FIN, not RST: a reset could reach the
            # peer before the rejection it is to read
            while sock.recv(1 << 16, socket.MSG_DONTWAIT):
                pass
        except OSError:  # nothing more to read (or the peer went): close
            pass
        close_socket(sock)
        self._report(peer_text(client_address), calling, called, address, own_ae_title,
                     result=1, source=1, reason=3)
        return False

    def _on_rejected(self, event) -> None:
        assoc = event.assoc
        request, answer = assoc.requestor.primitive, assoc.acceptor.primitive
        self._report(f"{assoc.requestor.address}:{assoc.requestor.port}", str(request.calling_ae_title).strip(),
                     str(request.called_ae_title).strip(), str(assoc.requestor.address), assoc.ae.ae_title,
                     result=getattr(answer, "result", None), source=getattr(answer, "result_source", None),
                     reason=int(getattr(answer, "diagnostic", 1) or 1))

    def _report(self, peer: str, calling: str, called: str, address: str, own_ae_title: str, result, source,
                reason: int) -> None:
        """Log a rejection and pass its record to ``on_rejected`` (class docstring)."""
        why = REJECT_REASONS.get(reason, f"reason {reason}")
        if int(result or 1) == 2:
            why = f"{self.max_associations} associations of senders off the allow-list are open (transient: try again)"
        elif reason == 3 and self.allow is not None:
            why += ": " + self.allow.why_not(calling, address)
        elif reason == 7:
            why += f": {called!r} is not this receiver's AE title {own_ae_title!r}"
        log.warning("rejected an association from %s (calling AE title %r, called %r): %s (A-ASSOCIATE-RJ "
                    "result %s, source %s, reason %d)", peer, calling, called, why,
                    "?" if result is None else result, "?" if source is None else source, reason)
        self.on_rejected({"peer": peer, "calling_ae_title": calling, "called_ae_title": called, "reason": reason,
                          "why": why})


def close_socket(sock) -> None:
    """Shut ``sock`` both ways and close it; one closed already is left as it is. The association's
    reader then finds it closed and ends (pynetdicom does not close it itself after an abort)."""
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except (AttributeError, OSError):
        pass
    try:
        sock.close()
    except (AttributeError, OSError):
        pass


class ConnectionGuard:
    """The bounds of every connection (module docstring): :meth:`handlers` gives the receiver's
    server an ``EVT_CONN_OPEN`` handler, which runs on the connection's thread before any PDU is
    read (after the TLS handshake, when there is one) and bounds its socket's reads and sends by
    ``timeout_s``, its PDUs by ``max_pdu_bytes``, its data sets by ``max_object_bytes``, and the
    data sets all connections hold while receiving them by ``max_in_flight_bytes``
    (:attr:`in_flight_bytes`): the connection whose fragment passes it is closed."""

    def __init__(self, timeout_s: float, max_pdu_bytes: int = MAX_PDU_BYTES, max_object_bytes: int = MAX_OBJECT_BYTES,
                 max_in_flight_bytes: int = MAX_IN_FLIGHT_BYTES, first_bytes_wait_s: float = FIRST_BYTES_WAIT_S,
                 on_silent: Callable[[str], object] | None = None):
        self.timeout_s, self.max_pdu_bytes, self.max_object_bytes = float(timeout_s), int(max_pdu_bytes), \
            int(max_object_bytes)
        self.max_in_flight_bytes = int(max_in_flight_bytes)
        self.first_bytes_wait_s = min(float(first_bytes_wait_s), self.timeout_s)
        self.on_silent = on_silent
        self.in_flight_bytes = 0  # the data set bytes every connection holds, received so far
        self._lock = threading.Lock()

    def handlers(self) -> list:
        from pynetdicom import evt

        return [(evt.EVT_CONN_OPEN, self._on_open)]

    def await_first_bytes(self, sock, client_address) -> bool:
        """Whether a new connection sent its first bytes within ``first_bytes_wait_s``, waited for
        in ``select`` (not polling) on its own thread before pynetdicom makes an association of it
        (:data:`FIRST_BYTES_WAIT_S`); one that sent none is closed and ``on_silent(peer)`` called."""
        try:
            ready, _, _ = select.select([sock], [], [], self.first_bytes_wait_s)
        except (OSError, ValueError):  # closed already
            return False
        if ready:
            return True
        peer = peer_text(client_address)
        log.info("closed the connection from %s: it sent nothing within %g s of connecting", peer,
                 self.first_bytes_wait_s)
        close_socket(sock)
        if self.on_silent is not None:
            self.on_silent(peer)
        return False

    def _on_open(self, event) -> None:
        from pynetdicom import evt

        transport, assoc = event.assoc.dul.socket, event.assoc
        peer = peer_text(event.address)
        try:
            transport.socket.settimeout(self.timeout_s)
        except (AttributeError, OSError):  # closed already: a refused TLS handshake
            return
        refused: list[str] = []
        read, limit, held = transport.recv, self.max_pdu_bytes, [0]

        def close(why: str) -> None:
            log.warning("closed the connection from %s: %s", peer, why)
            close_socket(transport.socket)

        def recv(n: int):  # pynetdicom reads a PDU's 6-byte header, then the length it announces
            if refused or n > limit:
                close(why := refused[0] if refused else f"it announced a PDU of {n} bytes (more than {limit})")
                raise ConnectionAbortedError(why)  # pynetdicom's "connection closed"
            try:
                return read(n)
            except TimeoutError:
                close(f"a PDU begun was left unfinished for {self.timeout_s} s")
                raise

        def on_data(event) -> None:  # each PDU read: the data set fragments of P-DATA-TF (PS3.8 §9.3.5)
            data, at = event.data, 6
            while data[:1] == b"\x04" and at + 6 <= len(data) and not refused:
                length, control = int.from_bytes(data[at:at + 4], "big"), data[at + 5]
                if not control & 1:  # a data set's fragment (bit 1 set: its last)
                    with self._lock:
                        held[0] += length - 2
                        self.in_flight_bytes += length - 2
                        if held[0] > self.max_object_bytes:  # the next read closes the connection
                            refused.append(f"its data set passed {self.max_object_bytes} bytes")
                        elif self.in_flight_bytes > self.max_in_flight_bytes:
                            refused.append(f"the data sets being received over all connections passed "
                                           f"{self.max_in_flight_bytes} bytes (MAX_IN_FLIGHT_BYTES)")
                        if control & 2 or refused:  # whole (the handler's now), or to be dropped
                            self.in_flight_bytes -= held[0]
                            held[0] = 0
                if refused:  # its socket reads as ended now: the read that closes it comes at once,
                    try:     # not with the sender's next PDU (which may never come)
                        transport.socket.shutdown(socket.SHUT_RD)
                    except (AttributeError, OSError):  # closed already
                        pass
                at += 4 + length

        def on_close(event) -> None:  # a message cut short: its bytes are no longer held
            with self._lock:
                self.in_flight_bytes -= held[0]
                held[0] = 0

        transport.recv = recv
        assoc.bind(evt.EVT_DATA_RECV, on_data)
        assoc.bind(evt.EVT_CONN_CLOSE, on_close)


def listening_error(host: str, port: int, exc: OSError) -> OSError:
    """``exc`` of a failed bind on ``host:port``, worded with both and what to do."""
    code = exc.errno or errno.EADDRINUSE
    hint = {errno.EADDRINUSE: "another receiver or program listens there: stop it or choose another port",
            errno.EADDRNOTAVAIL: "this machine has no such address: bind one of its own, or 0.0.0.0",
            errno.EACCES: "ports below 1024 need privileges: choose a port from 1024 up"}.get(code, "")
    return OSError(code, f"cannot listen on {host}:{port}: {exc.strerror or exc}" + (f" ({hint})" if hint else ""))


def check_listening_address(host: str, port: int) -> None:
    """Raise :func:`listening_error`'s OSError unless ``host:port`` can be bound now (port 0: any
    free one, always): bound with ``SO_REUSEADDR`` as the receiver's server binds, then closed."""
    host, port = check_host(host), check_port(port)
    if port == 0:
        return
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                                             flags=socket.AI_PASSIVE)[0]
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(address)
    except socket.gaierror as exc:
        raise OSError(errno.EADDRNOTAVAIL, f"cannot listen on {host}:{port}: {exc.strerror}") from None
    except OSError as exc:
        raise listening_error(host, port, exc) from None
