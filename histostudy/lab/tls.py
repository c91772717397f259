"""DICOM over TLS for the live receiver and its sender (§II-A; DICOM PS3.15 Annex B):
:class:`TLSConfig`, the PEM files of one end, each connection's handshake on its own thread
(docs/receiver.md, "TLS").
"""

from __future__ import annotations

import dataclasses
import logging
import os
import ssl
from collections.abc import Callable
from pathlib import Path

from .access import peer_text

__all__ = ["TLSConfig"]

log = logging.getLogger("histostudy.lab.receiver")  # the receiver's log, where its users look


@dataclasses.dataclass(frozen=True)
class TLSConfig:
    """The PEM files of one end of a TLS connection (DICOM PS3.15 Annex B; TLS 1.2 at least).

    Args:
        cert: this end's certificate (chain); the receiver needs one, a sender only for mutual
            authentication.
        key: its private key (unencrypted PEM), given with ``cert`` (None: in ``cert``'s file).
        ca: the CA certificate(s) that sign the other end's: for the receiver, the clients' (given:
            every client must present a certificate it signed); for a sender, the receiver's (None:
            the system's trusted CAs).

    Raises:
        ValueError: a path that is not a non-empty string or path, or a ``key`` without ``cert``.
        FileNotFoundError: a file that does not exist.
    """

    cert: str | os.PathLike | None = None
    key: str | os.PathLike | None = None
    ca: str | os.PathLike | None = None

    def __post_init__(self):
        for name in ("cert", "key", "ca"):
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, (str, os.PathLike)) or not str(value):
                raise ValueError(f"tls {name} must be a PEM file path or None, got {value!r}")
            if not Path(value).is_file():
                raise FileNotFoundError(f"tls {name} {str(value)!r}: no such file (a PEM file was expected)")
        if self.key is not None and self.cert is None:
            raise ValueError(f"tls key {str(self.key)!r} was given without its certificate (cert)")

    def server_context(self) -> ssl.SSLContext:
        """The receiver's context: its certificate, and with ``ca`` the clients' required."""
        if self.cert is None:
            raise ValueError("tls cert must be given for the receiver: the certificate it presents to senders")
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        self._load(context)
        if self.ca is not None:
            context.verify_mode = ssl.CERT_REQUIRED
        return context

    def client_context(self) -> ssl.SSLContext:
        """A sender's context: the receiver's certificate checked (against ``ca``, and its name or
        address against the one called), this end's presented if given."""
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # verifies the peer and its host name
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        if self.ca is None:
            context.load_default_certs(ssl.Purpose.SERVER_AUTH)
        self._load(context)
        return context

    def _load(self, context: ssl.SSLContext) -> None:
        try:
            if self.cert is not None:
                context.load_cert_chain(self.cert, self.key)
            if self.ca is not None:
                context.load_verify_locations(cafile=self.ca)
        except (ssl.SSLError, ValueError) as exc:
            raise ValueError(f"tls files cert={self.cert!r}, key={self.key!r}, ca={self.ca!r} cannot be loaded "
                             f"(PEM certificate, its unencrypted key, CA certificates expected): {exc}") from None


def tls_context(tls, name: str = "tls", *, server: bool) -> ssl.SSLContext | None:
    """``tls`` (None, a :class:`TLSConfig` or an ``ssl.SSLContext`` of that side) as an SSLContext."""
    if tls is None or isinstance(tls, ssl.SSLContext):
        if tls is not None and (tls.protocol == ssl.PROTOCOL_TLS_CLIENT) == server:
            side = "server (ssl.PROTOCOL_TLS_SERVER)" if server else "client (ssl.PROTOCOL_TLS_CLIENT)"
            raise ValueError(f"{name} must be an ssl.SSLContext for the {side} side, got {tls.protocol!r}")
        return tls
    if isinstance(tls, TLSConfig):
        return tls.server_context() if server else tls.client_context()
    raise ValueError(f"{name} must be None, a histostudy.lab.TLSConfig or an ssl.SSLContext, got {tls!r}")


class ServerTLS:
    """What pynetdicom's server is given as its ``ssl_context``: a wrapper of ``context`` whose
    ``wrap_socket`` defers the handshake to :meth:`handshake` (module docstring).

    ``on_refused(peer, exc)`` is called for each failed handshake (``peer``: ``"address:port"``).
    """

    def __init__(self, context: ssl.SSLContext, timeout_s: float, on_refused: Callable[[str, Exception], object]):
        self.context, self.timeout_s, self.on_refused = context, float(timeout_s), on_refused

    def wrap_socket(self, sock, server_side: bool = True, **kwargs):
        return self.context.wrap_socket(sock, server_side=True, do_handshake_on_connect=False)

    def handshake(self, event) -> None:
        """The handshake of a new connection (an ``EVT_CONN_OPEN`` handler, on its thread), bounded
        by the timeout; a failed one closes the connection before any DICOM is read from it."""
        sock = event.assoc.dul.socket.socket
        peer = peer_text(event.address)
        try:
            sock.settimeout(self.timeout_s)
            sock.do_handshake()
            sock.settimeout(None)  # pynetdicom polls the socket and reads it blocking
        except (OSError, ValueError) as exc:
            log.warning("refused a TLS connection from %s: %s", peer, exc)
            try:
                sock.close()  # the association's reader finds it closed and ends it
            finally:
                self.on_refused(peer, exc)
            return
        subject = dict(pair for rdn in (sock.getpeercert() or {}).get("subject", ()) for pair in rdn)
        log.info("TLS connection from %s (%s), client certificate: %s", peer, sock.version(),
                 subject.get("commonName", "none asked for"))
