"""``histostudy send``: DICOM objects to a Storage SCP (C-STORE), as DCMTK's ``storescu`` does, e.g.
a recorded cine to ``histostudy listen``."""

from __future__ import annotations

import time

from ..console import add_command, elapsed_since, emit, fail, log

__all__ = ["add_send"]


def add_send(sub, parents) -> None:
    snd = add_command(
        sub, "send", parents, help="send DICOM files to a C-STORE receiver (as storescu does)",
        description="Store DICOM objects on a Storage SCP in one association (C-STORE), in the order given: "
                    "e.g. a recorded cine to `histostudy listen`. --paced sends each frame no earlier than its "
                    "acquisition time allows, as a C-arm streams it. Prints a JSON line with each object's "
                    "status; exit status 1 when an object was not stored.",
        example="histostudy send 127.0.0.1 11112 cine/A.dcm cine/B.dcm --wait-s 60\n"
                "histostudy send 127.0.0.1 11112 cine/*.dcm --paced --calling-ae CARM_A")
    snd.add_argument("peer", help="the receiver's host name or address")
    snd.add_argument("port", type=int, help="the receiver's TCP port")
    snd.add_argument("files", nargs="+", help="DICOM files to store")
    snd.add_argument("--called-ae", default="HISTOSTUDY", help="the receiver's AE title (default HISTOSTUDY)")
    snd.add_argument("--calling-ae", default="HISTOSTUDY_SCU", help="this sender's AE title (default HISTOSTUDY_SCU)")
    snd.add_argument("--paced", action="store_true",
                     help="at the acquisition's pace (the frames' times), not all at once")
    snd.add_argument("--wait-s", type=float, default=0.0,
                     help="try to connect for up to this many seconds while the receiver starts (default 0: once)")
    snd.add_argument("--timeout-s", type=float, default=30.0,
                     help="seconds to wait for the association and for each response (default 30)")
    snd.add_argument("--tls-ca", default=None, metavar="PEM",
                     help="send over TLS, checking the receiver's certificate against this CA")
    snd.add_argument("--tls-cert", default=None, metavar="PEM", help="this sender's certificate (mutual TLS)")
    snd.add_argument("--tls-key", default=None, metavar="PEM", help="its private key (default: in --tls-cert's file)")
    snd.set_defaults(run=run_send)


def run_send(args) -> int:
    from pathlib import Path

    from histostudy.lab import TLSConfig, send_frames, stream_frames

    t0 = time.monotonic()
    missing = [f for f in args.files if not Path(f).is_file()]
    if missing:
        return fail("send", f"no such file: {', '.join(map(repr, missing))}")
    if args.wait_s < 0 or args.wait_s != args.wait_s:
        return fail("send", f"--wait-s must be >= 0 seconds, got {args.wait_s!r}")
    if (args.tls_cert or args.tls_key) and not args.tls_ca:
        return fail("send", "--tls-cert and --tls-key need --tls-ca: the CA that signed the receiver's certificate")
    tls = None if args.tls_ca is None else TLSConfig(args.tls_cert, args.tls_key, args.tls_ca)
    options = dict(ae_title=args.called_ae, calling_ae_title=args.calling_ae, timeout_s=args.timeout_s, tls=tls)
    if not _reachable(args.peer, args.port, args.wait_s):
        return fail("send", f"nothing listens on {args.peer}:{args.port} (waited {args.wait_s:g} s, --wait-s)", 1)
    try:
        if args.paced:
            statuses = [sent.status for sent in stream_frames(args.files, args.peer, args.port, **options)]
        else:
            statuses = send_frames(args.files, args.peer, args.port, **options)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        return fail("send", exc)
    except (ConnectionError, OSError) as exc:
        return fail("send", exc, 1)
    failed = [f for f, status in zip(args.files, statuses) if status != 0]
    log.info(f"sent {len(statuses) - len(failed)} of {len(statuses)} objects to {args.peer}:{args.port}"
             + (f"; not stored: {', '.join(failed)}" if failed else ""))
    emit({"command": "send", "peer": args.peer, "port": args.port, "statuses": statuses,
          "files": list(args.files), "n_stored": len(statuses) - len(failed), "wall_s": elapsed_since(t0)})
    return 1 if failed else 0


def _reachable(host: str, port: int, wait_s: float) -> bool:
    """Whether a TCP connection to ``host:port`` opens, tried until ``wait_s`` seconds have passed
    (the receiver may still be loading its models)."""
    import socket

    deadline = time.monotonic() + wait_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=2.0):
                return True
        except OSError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.25)
