"""``histostudy listen``: a DICOM C-STORE receiver of live C-arm frames -> one pose per biplane
pair (§II-A, the tracking of docs/tracking.md)."""

from __future__ import annotations

import argparse
import time

from ..console import Steps, add_command, elapsed_since, emit, fail, log
from ._inputs import WORLD_FRAME, model_from_args, positive_int

__all__ = ["add_listen"]


def add_listen(sub, parents) -> None:
    lis = add_command(
        sub, "listen", parents,
        help="receive live C-arm frames over DICOM (C-STORE) and write a pose per biplane pair",
        description="Receive the C-arm's frames as a DICOM Storage SCP, pair the two planes by acquisition "
                    "time and write one pose per pair (JSON lines, --output), tracking from the last pose. The "
                    "newest pair is posed and older waiting ones are dropped. stdout: a JSON line when listening "
                    "(host, port) and one with the statistics at the end; stderr: a line per pose (-q: none).",
        example="histostudy listen --port 11112 --views views.json --output poses.jsonl\n"
                "histostudy listen --port 11112 --views views.json --host 0.0.0.0 --allow CARM_A@192.0.2.21")
    lis.add_argument("--port", type=int, required=True, help="TCP port to listen on (0: any free port)")
    lis.add_argument("--views", required=True, help="views JSON: one view per plane, named as the planes' "
                                                    "SeriesDescription")
    lis.add_argument("--host", default="127.0.0.1",
                     help="address to bind (default 127.0.0.1: this machine only; 0.0.0.0: every interface, e.g. "
                          "for the C-arm's network, with --allow or --modalities)")
    lis.add_argument("--ae-title", default="HISTOSTUDY", help="this receiver's AE title (default HISTOSTUDY)")
    lis.add_argument("--output", default="poses.jsonl",
                     help="JSON lines, one pose per pair (default poses.jsonl); an earlier run's file is continued, "
                          "its pairs numbered on")
    lis.add_argument("--max-pairs", type=int, default=None, help="stop after this many pairs")
    lis.add_argument("--timeout-s", type=float, default=None, help="stop after this many seconds")
    lis.add_argument("--seed", type=int, default=0, help="seed of the estimates' random draws (default 0)")
    lis.add_argument("--transducer", default=None, metavar="DIR",
                     help="the transducer's CAD meshes, one file per feature class (as for `histostudy pose`); "
                          "default: the paper's digital model")
    lis.add_argument("--fast", action=argparse.BooleanOptionalAction, default=True,
                     help="track on the region of the last pose (pose.Tracker(fast=True), the default: "
                          "docs/tracking.md); --no-fast: every pair on the full frames")
    lis.add_argument("--warm-up", action=argparse.BooleanOptionalAction, default=True,
                     help="run the tracker once on a synthetic pair before the first frame (pose.Tracker.warm_up, "
                          "the default), so the first pair does not wait for compiled kernels; the poses are the same")
    lis.add_argument("--max-queued-pairs", type=_queue_bound, default=1, metavar="N|all",
                     help="the most pairs waiting for a pose: a newer pair drops the oldest rather than fall behind "
                          "(counted in the stats; default 1: the newest pair only; all: keep every pair, for a cine "
                          "sent at once)")
    lis.add_argument("--allow", action="append", default=[], metavar="AE[@IP]",
                     help="a sender allowed: its calling AE title and, optionally, the IP address it must call from "
                          "(repeat for each; with --modalities, both lists). Others are rejected at association "
                          "(A-ASSOCIATE-RJ). "
                          "Default: any calling AE title, with a warning; the called AE title is checked always")
    lis.add_argument("--modalities", default=None, metavar="FILE",
                     help='JSON allow-list: {"modalities": {"carm_a": {"ae_title": "CARM_A", "host": '
                          '"192.168.10.21"}, ...}} (host optional)')
    lis.add_argument("--tls-cert", default=None, metavar="PEM", help="receive over TLS: this receiver's certificate")
    lis.add_argument("--tls-key", default=None, metavar="PEM", help="its private key (default: in --tls-cert's file)")
    lis.add_argument("--tls-ca", default=None, metavar="PEM",
                     help="CA certificate(s): every sender must present a certificate it signed (mutual TLS)")
    lis.set_defaults(run=run_listen)


def _queue_bound(text: str) -> int | None:
    """``--max-queued-pairs``: an integer >= 1, or ``all`` (None: no bound)."""
    if text.strip().lower() == "all":
        return None
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1 or 'all', got {text!r}") from None


def run_listen(args) -> int:
    from histostudy.imaging import load_views
    from histostudy.lab import AllowList, ReceiverConfig, TLSConfig, listen, load_modalities, parse_allow

    t0 = time.monotonic()

    def started(port: int) -> None:  # the bound port (--port 0: a free one), for whoever sends the frames
        senders = "any calling AE title (no --allow or --modalities)" if allow is None else \
            ", ".join(map(str, allow.modalities))
        link = "plain TCP" if tls is None else "TLS" + (", client certificates required" if tls.ca else "")
        emit({"event": "listening", "host": args.host, "port": port, "ae_title": args.ae_title,
              "output": str(args.output), "tls": tls is not None})
        log.info(f"listening on {args.host}:{port} as {args.ae_title}; poses to {args.output}")
        log.info(f"senders allowed: {senders}; {link}")

    try:
        listed = [parse_allow(text) for text in args.allow]
        if args.modalities is not None:
            listed += load_modalities(args.modalities).modalities
        allow = AllowList(tuple(listed)) if listed else None
        tls = None
        if (args.tls_key or args.tls_ca) and not args.tls_cert:
            raise ValueError("--tls-key and --tls-ca need --tls-cert: the certificate this receiver presents")
        if args.tls_cert:
            tls = TLSConfig(args.tls_cert, args.tls_key, args.tls_ca)
        config = ReceiverConfig(output_path=args.output, ae_title=args.ae_title, port=args.port, host=args.host,
                                max_queued_pairs=args.max_queued_pairs, fast=args.fast, warm_up=args.warm_up,
                                allow=allow, tls=tls)
        views = load_views(args.views)
        model = model_from_args(args)
        with Steps(1, enabled=args.progress and args.warm_up, label="listen") as steps:
            steps.step("loading the models and warming up")
            stats = listen(views, config, model=model, max_pairs=args.max_pairs, timeout_s=args.timeout_s,
                           seed=args.seed, on_start=_after(started, steps), on_summary=log.info)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:
        return fail("listen", exc)
    latency = stats["latency_s"]
    figures = ", ".join(f"{k} {latency[k]:.3f}" for k in ("p50", "p90", "p99", "max") if latency[k] is not None)
    log.info(f"listen: {stats['pairs_processed']} pairs posed ({stats['pairs_accepted']} accepted, "
             f"{stats['pairs_errors']} errors), {stats['pairs_skipped']} dropped; latency s: {figures or 'no pose'}")
    emit({"event": "summary", "command": "listen", "output": str(args.output), "frame": WORLD_FRAME,
          "wall_s": elapsed_since(t0), **stats})
    return 0


def _after(started, steps: Steps):
    """``on_start`` that first closes the warm-up's progress bar (the receiver is ready)."""
    def on_start(port: int) -> None:
        steps.close()
        started(port)
    return on_start
