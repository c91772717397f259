"""pynetdicom's threaded association server with an admission check on each new connection's own
thread, before an association is made of it: a connection refused there (silent, a stranger) never
starts the association's polling threads nor counts among its associations (docs/receiver.md,
"Who may send").
"""

from __future__ import annotations

import logging
import socketserver
import threading
from collections.abc import Callable

from pynetdicom.transport import ThreadedAssociationServer

log = logging.getLogger("histostudy.lab.receiver")


class AdmittingServer(ThreadedAssociationServer):
    """A :class:`pynetdicom.transport.ThreadedAssociationServer` that hands each connection to
    ``admit(sock, client_address) -> bool`` on the connection's thread first; only an admitted one
    goes on to pynetdicom (``EVT_CONN_OPEN``, the association). ``admit`` closes what it refuses.
    Made by :func:`start_admitting_server`, not by ``AE.start_server``: it is not among the AE's
    servers, and :meth:`shutdown` stops it alone."""

    def __init__(self, *args, admit: Callable[[object, tuple], bool], **kwargs):
        self.admit = admit
        super().__init__(*args, **kwargs)

    def process_request_thread(self, request, client_address) -> None:
        try:
            admitted = self.admit(request, client_address)
        except Exception:  # an admission that cannot be judged refuses: it fails closed
            log.exception("the admission of a connection from %s failed; closing it", client_address)
            admitted = False
        if admitted:
            super().process_request_thread(request, client_address)
        else:
            self.shutdown_request(request)

    def shutdown(self) -> None:
        """Stop serving and close the listening socket (the AE's associations are the AE's to abort)."""
        socketserver.BaseServer.shutdown(self)
        self.server_close()


def start_admitting_server(ae, address: tuple[str, int], admit: Callable[[object, tuple], bool],
                           listen_backlog: int, ssl_context=None, evt_handlers: list | None = None
                           ) -> AdmittingServer:
    """Bind an :class:`AdmittingServer` of ``ae`` on ``address``, listen with ``listen_backlog``
    and serve in a daemon thread.

    Args:
        ae: the ``pynetdicom.AE`` whose contexts, AE title and limits the server serves.
        address: ``(host, port)``; port 0 takes a free one (``server.server_address`` says which).
        admit: ``admit(sock, client_address) -> bool``, per connection on its thread (the class).
        listen_backlog: connections the kernel queues before ``accept`` (socketserver's is 5: under
            a burst of connections, a scanner's, the kernel drops the C-arm's SYN, and TCP retries it
            after 1, 3, 7 s).
        ssl_context: as ``AE.start_server``'s (:class:`.tls.ServerTLS`), or None.
        evt_handlers: as ``AE.start_server``'s.

    Returns:
        The server, serving.

    Raises:
        OSError: the address cannot be bound (nothing is left listening).
    """
    server = ae.make_server(address, ssl_context=ssl_context, evt_handlers=evt_handlers,
                            server_class=AdmittingServer, admit=admit)
    try:
        server.socket.listen(int(listen_backlog))
    except BaseException:
        server.server_close()
        raise
    threading.Thread(target=server.serve_forever, name="histostudy-receiver-server", daemon=True).start()
    return server
