"""Live C-arm frames received over DICOM (C-STORE), paired across the planes and posed (§II-A):
:class:`FrameReceiver`, a Storage SCP that writes one pose per biplane pair to a JSON-lines file as it
comes, set up by a :class:`ReceiverConfig`. The chain per object, the newest-pair rule, the
rejections and who may send are in docs/receiver.md. Units: mm, seconds.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import logging
import os
import ssl
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from histostudy.core.checks import check_ae_title, check_count, check_host, check_port, check_positive
from histostudy.imaging import View
from histostudy.pose import Tracker, TrackingConfig
from histostudy.transducer import TransducerModel

from .access import (
    FIRST_BYTES_WAIT_S,
    MAX_IN_FLIGHT_BYTES,
    MAX_OBJECT_BYTES,
    MAX_PDU_BYTES,
    AllowList,
    AssociationGate,
    ConnectionGuard,
    listening_error,
)
from .instances import InstanceRegister, pixel_fingerprint
from .pairing import DEFAULT_FRAME_INTERVAL_S, BiplanePairer, PlaneFrame
from .pose_lines import PoseLineFile
from .pose_worker import PoseWorker
from .receiver_counts import ReceiverCounts
from .tls import ServerTLS, tls_context
from .xray_objects import (
    STATUS_OUT_OF_RESOURCES,
    STATUS_SOP_CLASS_NOT_SUPPORTED,
    STATUS_SUCCESS,
    VIEW_MATCH_TOLERANCE_MM,
    XRayObjectRejected,
    read_c_store,
    rejection_response,
    storage_application_entity,
)

if TYPE_CHECKING:
    from pynetdicom import AE

    from .admitting_server import AdmittingServer

__all__ = ["FrameReceiver", "ReceiverConfig"]

log = logging.getLogger(__name__)

#: How long (s) :meth:`FrameReceiver.stop` waits for open associations to release before aborting them.
RELEASE_GRACE_S = 1.0
#: The listening socket's backlog of connections not yet accepted.
LISTEN_BACKLOG = 128


#: The settings of :class:`ReceiverConfig`, by name (those :meth:`ReceiverConfig.split` takes).
_SETTINGS = ("output_path", "ae_title", "port", "host", "network_timeout_s", "allow", "tls", "air_value",
             "match_tolerance_mm", "tolerance_s", "default_interval_s", "max_queued_pairs", "pipeline", "warm_up",
             "fast")


@dataclasses.dataclass(frozen=True)
class ReceiverConfig:
    """The settings of a :class:`FrameReceiver`: where it listens and writes, who may send, how frames
    are paired and queued, and how the tracker starts. Checked on construction.

    Args:
        output_path: the JSON-lines file the poses are appended to (one whole line per pair, written
            as it comes); an earlier run's file is continued, its pairs numbered on.
        ae_title: the receiver's AE title (the senders' "called AE title"), 1-16 ASCII characters.
        port: TCP port to listen on; 0: a free one (:meth:`FrameReceiver.start` returns it).
        host: the address to bind (default loopback; ``"0.0.0.0"`` for every interface).
        network_timeout_s: how long an idle or half-open association, or a PDU begun, is kept (s;
            :class:`~.access.ConnectionGuard`).
        allow: who may send: an :class:`~.access.AllowList` (e.g. :func:`~.access.load_modalities`),
            or :class:`~.access.Modality` objects and ``"AE[@IP]"`` texts (kept as an AllowList); an
            association from another calling AE title, or from another address than its modality's,
            is rejected at negotiation. None: any calling AE title may send, with a warning in the
            log. The called AE title must be ``ae_title`` either way.
        tls: None (plain TCP), a :class:`~.tls.TLSConfig` (the receiver's ``cert`` and ``key``; with
            ``ca``, every sender must present a certificate that CA signed) or a server-side
            ``ssl.SSLContext`` (a TLSConfig is kept as the context it loads).
        air_value: ``I0`` for the line integrals (modality units); None: each frame's maximum.
        match_tolerance_mm: how far (mm at the isocentre) the tags' geometry may project from a
            plane's view (:func:`.xray_objects.decode_xray_object`); None: not checked.
        tolerance_s: the largest time difference of a pair's two frames (s; None: half the frame
            interval), as :class:`~.pairing.BiplanePairer`'s.
        default_interval_s: the frame interval assumed for a frame without one (s), as
            :class:`~.pairing.BiplanePairer`'s.
        max_queued_pairs: the most pairs waiting for the pose; beyond, the oldest is dropped (counted
            in ``pairs_dropped_stale`` and ``pairs_skipped``, no line) so that the poses follow a live
            stream that outpaces them. 1: the newest complete pair only; None: every pair waits for
            its line (batch use), however far behind the stream.
        pipeline: overlap the next waiting pair's segmentation with the current pair's refinement
            (:meth:`~histostudy.pose.Tracker.track`). Off by default: the pair taken ahead can no
            longer be dropped for a newer one (docs/tracking-alternatives.md, "The receiver").
        warm_up: :meth:`FrameReceiver.start` runs :meth:`~histostudy.pose.Tracker.warm_up` once
            listening, before the pose worker starts, so that the first pair does not wait for
            compiled kernels; the poses are the same either way (``stats()["warm_up_s"]``).
        fast: the tracker's warm path (:class:`~histostudy.pose.Tracker`'s ``fast``): True or a
            :class:`~histostudy.pose.TrackingConfig`. True is ``TrackingConfig(scratch_full_frames=False)``
            here: a refused estimate from scratch is not tried again on the full frames, which held
            the stream seconds for few accepted poses (docs/tracking.md, "Warm starts that hold").
            False: every update on the full frames, as :func:`~histostudy.pose.estimate_pose`.

    Raises:
        ValueError: a setting out of its range (the message names it, its value and what was
            expected): an empty ``output_path``, an AE title, port or host that is not one, a
            ``network_timeout_s``, ``air_value``, ``match_tolerance_mm``, ``tolerance_s`` or
            ``default_interval_s`` that is not a finite number > 0, a ``max_queued_pairs`` that is
            not an integer >= 1 or None, ``pipeline`` or ``warm_up`` not a bool, or an ``allow`` or
            ``tls`` of another kind.
    """

    output_path: str | os.PathLike = "poses.jsonl"
    ae_title: str = "HISTOSTUDY"
    port: int = 11112
    host: str = "127.0.0.1"
    network_timeout_s: float = 30.0
    allow: object = None
    tls: object = None
    air_value: float | None = None
    match_tolerance_mm: float | None = VIEW_MATCH_TOLERANCE_MM
    tolerance_s: float | None = None
    default_interval_s: float = DEFAULT_FRAME_INTERVAL_S
    max_queued_pairs: int | None = 1
    pipeline: bool = False
    warm_up: bool = True
    fast: bool | TrackingConfig = True

    def __post_init__(self):
        if not isinstance(self.output_path, (str, os.PathLike)) or not str(self.output_path):
            raise ValueError(f"output_path must be a file path, got {self.output_path!r}")
        checked = {
            "ae_title": check_ae_title(self.ae_title), "port": check_port(self.port), "host": check_host(self.host),
            "network_timeout_s": check_positive(self.network_timeout_s, "network_timeout_s",
                                                what="a finite number of seconds > 0"),
            "allow": AllowList.of(self.allow), "tls": tls_context(self.tls, server=True),
        }
        check_positive(self.air_value, "air_value", optional=True, what="a finite intensity > 0")
        check_positive(self.match_tolerance_mm, "match_tolerance_mm", optional=True,
                       what="a finite number > 0 (mm at the isocentre)")
        check_positive(self.tolerance_s, "tolerance_s", optional=True, what="a finite time > 0 s")
        check_positive(self.default_interval_s, "default_interval_s", what="a finite interval > 0 s")
        check_count(self.max_queued_pairs, "max_queued_pairs", optional=True)
        for name in ("pipeline", "warm_up"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    @classmethod
    def split(cls, options: dict, **settings) -> tuple[ReceiverConfig, dict]:
        """A config from keyword arguments that mix its settings with others (e.g. the tracker's).

        Args:
            options: keyword arguments; those named as a setting of this class go to the config.
            **settings: more settings (``options`` overrides them).

        Returns:
            The config, and the rest of ``options`` (a new dict).

        Raises:
            ValueError: as the constructor.
        """
        mine = {**settings, **{k: v for k, v in options.items() if k in _SETTINGS}}
        return cls(**mine), {k: v for k, v in options.items() if k not in _SETTINGS}


class FrameReceiver(PoseWorker):
    """A DICOM C-STORE receiver of live C-arm frames that writes a pose per biplane pair (§II-A).

    ``with FrameReceiver(views, ReceiverConfig(output_path="poses.jsonl", port=0)) as rx: ...`` — or
    :meth:`start` / :meth:`stop`, or :meth:`serve_forever`; :func:`.listening.listen` for the command line.

    Args:
        views: one view per plane (the paper: planes A and B, §II-D), named as the planes'
            ``SeriesDescription``; the pose uses these views (e.g. calibrated ones), the objects'
            tags only pick and check the plane. Unique names.
        config: the receiver's settings (:class:`ReceiverConfig`); None: its defaults.
        model: the digital model of eq. 3; None: ``TransducerModel.build(spacing_mm=0.47)`` (the
            paper's).
        seed: the tracker's random draws (an int or a ``numpy.random.Generator``): the same frames and
            seed give the same poses.
        on_pose: called with each record (a dict, as written) on the worker thread; its errors are
            logged, not raised.
        **tracker_options: :class:`~histostudy.pose.Tracker`'s ``segmenter``, ``orientation`` and
            ``options`` (a :class:`~histostudy.pose.PoseConfig`), and PoseConfig fields. Without
            ``options``, ``retry_hypotheses`` defaults to False and ``mode`` to ``"fast"``
            (Levenberg-Marquardt): live, the next pair is a frame interval away (docs/tracking.md,
            "A minute of moving cine").

    Raises:
        ValueError: ``views`` empty, not :class:`~histostudy.imaging.View` objects or with repeated
            names; ``config`` not a ReceiverConfig.
        TypeError: ``on_pose`` not callable.
    """

    def __init__(self, views: Sequence[View], config: ReceiverConfig | None = None, *,
                 model: TransducerModel | None = None, seed=0, on_pose: Callable[[dict], object] | None = None,
                 **tracker_options):
        views = [views] if isinstance(views, View) else list(views)
        if not views or not all(isinstance(v, View) for v in views):
            raise ValueError(f"views must be a non-empty sequence of histostudy.imaging.View, got {views!r}")
        names = [v.name for v in views]
        if len(set(names)) != len(names):
            raise ValueError(f"views must have unique names (the planes' SeriesDescription), got {names!r}")
        config = ReceiverConfig() if config is None else config
        if not isinstance(config, ReceiverConfig):
            raise ValueError(f"config must be a histostudy.lab.ReceiverConfig or None, got {config!r}")
        if on_pose is not None and not callable(on_pose):
            raise TypeError(f"on_pose must be callable (record -> None) or None, got {type(on_pose).__name__}")
        self.config = config
        allow, tls = config.allow, config.tls
        # ReceiverConfig's checks keep them as the AllowList and the server's SSLContext they stand for
        assert allow is None or isinstance(allow, AllowList)
        assert tls is None or isinstance(tls, ssl.SSLContext)
        self.allow, self.tls = allow, tls
        self.views = tuple(views)
        self.model = TransducerModel.build(spacing_mm=0.47) if model is None else model
        if tracker_options.get("options") is None:
            tracker_options.setdefault("retry_hypotheses", False)
            tracker_options.setdefault("mode", "fast")
        fast = TrackingConfig(scratch_full_frames=False) if config.fast is True else config.fast
        self.tracker = Tracker(self.model, self.views, rng=seed, fast=fast, **tracker_options)
        self.pairer = BiplanePairer(names, tolerance_s=config.tolerance_s, default_interval_s=config.default_interval_s)
        self.output_path = Path(config.output_path)
        self.ae_title, self.host, self.port = config.ae_title, config.host, config.port
        self.on_pose = on_pose
        self.air_value, self.match_tolerance_mm = config.air_value, config.match_tolerance_mm
        self.max_queued_pairs, self.network_timeout_s = config.max_queued_pairs, config.network_timeout_s
        self.max_pdu_bytes, self.max_object_bytes = MAX_PDU_BYTES, MAX_OBJECT_BYTES  # ConnectionGuard's bounds
        self.max_in_flight_bytes, self.first_bytes_wait_s = MAX_IN_FLIGHT_BYTES, FIRST_BYTES_WAIT_S
        self.pipeline, self.warm_up = config.pipeline, config.warm_up

        self._cv = threading.Condition()  # guards the pairer, the queue and the counters
        self._queue = collections.deque()
        self._ae: AE | None = None
        self._server: AdmittingServer | None = None
        self._worker: threading.Thread | None = None
        self._out = None
        self._first_index = 0  # the first pair's index: one past the last line of the file continued
        self._closing = self._stopped = False
        self._max_pairs = None
        self._t_free = time.perf_counter()  # when the worker last wrote a line (its pose time starts after)
        self._stats = ReceiverCounts(self.tracker.stats())
        self._counts = self._stats.counts
        self._instances = InstanceRegister()  # a C-STORE repeated is answered, not posed twice

    # --- life cycle -----------------------------------------------------------------------------

    def start(self) -> int:
        """Listen (non-blocking), warm the tracker up (``warm_up``), then open the output and start
        the pose worker. An output file of an earlier run is continued: a torn last line (a run
        killed while writing it) is cut off and the pairs are numbered on from its last line's
        (:class:`~.pose_lines.PoseLineFile`).

        Returns:
            The bound port (a free one where the config's ``port`` is 0).

        Raises:
            RuntimeError: this receiver was started already.
            OSError: the address cannot be bound (in use, not this machine's); it names the host and
                port, and is raised before the output is opened: nothing is created or written.
            ValueError: the output file's last line is not a pose line (before anything is bound).
        """
        from pynetdicom import evt

        from .admitting_server import start_admitting_server

        if self._server is not None or self._stopped:
            raise RuntimeError("this FrameReceiver was started already; make a new one")
        # a file of an earlier run is continued: its pairs numbered on (read before a frame can come)
        self._first_index = PoseLineFile(self.output_path).next_index()
        ae = storage_application_entity(self.ae_title, self.network_timeout_s)
        gate, guard = AssociationGate(self.allow, self._on_rejected), ConnectionGuard(
            self.network_timeout_s, self.max_pdu_bytes, self.max_object_bytes, self.max_in_flight_bytes,
            self.first_bytes_wait_s, on_silent=self._on_event("connections_silent"))
        gate.configure(ae)
        tls = None if self.tls is None else ServerTLS(self.tls, self.network_timeout_s, self._on_event("tls_refused"))
        # the TLS handshake first of pynetdicom's handlers, on the connection's thread (tls.ServerTLS)
        handlers = [*([] if tls is None else [(evt.EVT_CONN_OPEN, tls.handshake)]),
                    (evt.EVT_CONN_OPEN, _dimse_recv_first), *guard.handlers(), *gate.handlers(),
                    (evt.EVT_C_STORE, self._on_c_store), (evt.EVT_DIMSE_RECV, self._on_dimse_received),
                    (evt.EVT_ACCEPTED, self._on_event("associations")),
                    (evt.EVT_ABORTED, self._on_event("associations_aborted"))]

        def admit(sock, client_address) -> bool:  # each connection, before an association is made of it
            self._count("connections")
            return (guard.await_first_bytes(sock, client_address) and not self._stopped
                    and gate.screen(sock, client_address, self.ae_title))

        self._ae = ae
        try:
            self._server = start_admitting_server(ae, (self.host, self.port), admit, LISTEN_BACKLOG,
                                                  ssl_context=tls, evt_handlers=handlers)
        except OSError as exc:
            self.stop(drain=False)
            raise listening_error(self.host, self.port, exc) from None
        except BaseException:
            self.stop(drain=False)
            raise
        try:
            self._warm_up_tracker()
            self._out = PoseLineFile(self.output_path)
            self._out.open()  # numbered on from next_index(), read before any frame could come
            self._worker = threading.Thread(target=self._work, name="histostudy-pose-worker", daemon=True)
            self._worker.start()
        except BaseException:
            self.stop(drain=False)
            raise
        self.port = int(self._server.server_address[1])
        self._stats.t_started = time.perf_counter()
        log.info("receiving DICOM X-ray frames on %s:%d as %r%s%s; poses to %s", self.host, self.port,
                 self.ae_title, "" if self.tls is None else " over TLS",
                 "" if self.allow is None else f" from {', '.join(map(str, self.allow.modalities))}",
                 self.output_path)
        return self.port

    def stop(self, drain: bool = True) -> None:
        """Stop listening, let the worker finish — with ``drain`` every pair already received gets
        its pose, without it only the ones in progress (with ``pipeline``, the one posed and the one
        taken ahead) — and close the output. Objects arriving meanwhile are answered 0xA700; open
        associations get up to :data:`RELEASE_GRACE_S` (at most the network timeout) to release, so
        that a sender whose last object was stored is not aborted in its release, and are then
        aborted. Frames still waiting for a partner are counted as unpaired."""
        if self._stopped:
            return
        self._stopped = True
        with self._cv:
            self._closing = True  # from here on an object is answered 0xA700: no pair completes
            if not drain:
                self._counts["pairs_skipped"] += len(self._queue)
                self._queue.clear()
            self._cv.notify_all()
        if self._ae is not None:
            deadline = time.monotonic() + min(RELEASE_GRACE_S, self.network_timeout_s)
            while self._ae.active_associations and time.monotonic() < deadline:
                time.sleep(0.02)
            self._ae.shutdown()
        if self._server is not None:
            self._server.shutdown()
        if self._worker is not None:
            self._worker.join()
        with self._cv:
            self._counts["pairs_skipped"] += len(self._queue)  # beyond max_pairs
            self._queue.clear()
            unpaired = self.pairer.flush()
            self._counts["frames_unpaired"] += len(unpaired)
        if self._out is not None:
            self._out.close()
        log.info("receiver stopped: %s", {k: v for k, v in self.stats().items() if not isinstance(v, dict)})

    def __enter__(self) -> FrameReceiver:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def serve_forever(self, max_pairs: int | None = None, timeout_s: float | None = None) -> dict:
        """Receive (starting if needed) until Ctrl-C, until ``max_pairs`` pairs have their line, or
        for ``timeout_s`` seconds; then stop and return :meth:`stats`. On a timeout the pairs
        already received still get their poses; on Ctrl-C only the one in progress does."""
        check_count(max_pairs, "max_pairs", optional=True)
        check_positive(timeout_s, "timeout_s", optional=True, what="a finite number of seconds > 0")
        with self._cv:
            self._max_pairs = max_pairs
        if self._server is None:
            self.start()
        interrupted = False
        try:
            with self._cv:
                self._wait(lambda: self._closing or self._at_limit(), timeout_s)
        except KeyboardInterrupt:
            interrupted = True
            log.info("interrupted: stopping the receiver")
        finally:
            self.stop(drain=not interrupted)
        return self.stats()

    def wait_for_pairs(self, n: int, timeout_s: float) -> bool:
        """Block until ``n`` pairs have their line (True) or ``timeout_s`` passed (False)."""
        with self._cv:
            return self._wait(lambda: self._counts["pairs_processed"] >= n, timeout_s)

    def _wait(self, done: Callable[[], bool], timeout_s: float | None) -> bool:
        """Wait (holding the lock) until ``done()`` (True) or ``timeout_s`` passed (False; None:
        no limit), waking at least every 0.5 s so that Ctrl-C is seen."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not done():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return False
            self._cv.wait(0.5 if remaining is None else min(0.5, remaining))
        return True

    # --- the network side (pynetdicom's association threads) ------------------------------------

    def _on_rejected(self, record: dict) -> None:
        with self._cv:
            self._stats.add_association_rejection(record)

    def _count(self, counter: str, *_what) -> None:
        """One more ``counter``; a handler's arguments (``_what``: the event, the peer) aside."""
        with self._cv:
            self._counts[counter] += 1

    def _on_event(self, counter: str):
        """A handler (of a pynetdicom event, or a callback of the gate, guard or TLS) counting ``counter``."""
        return functools.partial(self._count, counter)

    def _on_dimse_received(self, event) -> None:
        """Answer at once a C-STORE request whose command names no SOP class (0x0122): pynetdicom
        drops such a request as invalid, unanswered, and its sender would wait out the network
        timeout (docs/receiver.md)."""
        from pynetdicom.dimse_messages import C_STORE_RQ
        from pynetdicom.dimse_primitives import C_STORE

        message = event.message
        if not isinstance(message, C_STORE_RQ) or str(message.command_set.get("AffectedSOPClassUID", "") or ""):
            return
        uid = str(message.command_set.get("AffectedSOPInstanceUID", "") or "")
        reason = "the C-STORE command names no Affected SOP Class UID (0000,0002)"
        with self._cv:
            self._counts["objects_received"] += 1
        answer = self._reject(STATUS_SOP_CLASS_NOT_SUPPORTED, uid, "", reason)
        response = C_STORE()
        response.MessageIDBeingRespondedTo = message.command_set.MessageID
        if uid:
            response.AffectedSOPInstanceUID = uid
        response.Status = answer.Status
        response.ErrorComment = answer.ErrorComment
        event.assoc.dimse.send_msg(response, message.context_id)

    def _on_c_store(self, event):
        """Read and check one object's header, pair its frames, queue completed pairs; answer at once
        (the pixels are converted by the worker, for the pairs it poses)."""
        t0 = time.perf_counter()
        sop_class = str(getattr(event.request, "AffectedSOPClassUID", "") or "")
        uid = str(getattr(event.request, "AffectedSOPInstanceUID", "") or "")
        with self._cv:
            self._counts["objects_received"] += 1
            closing = self._closing
        if closing:
            return self._reject(STATUS_OUT_OF_RESOURCES, uid, sop_class, "the receiver is stopping")
        try:
            frames = read_c_store(event, self.views, match_tolerance_mm=self.match_tolerance_mm)
            dataset = frames[0].dataset
            fingerprint = pixel_fingerprint(dataset)
        except XRayObjectRejected as exc:
            return self._reject(exc.status, uid, sop_class, exc.reason)
        instance = frames[0].instance_uid
        now = time.perf_counter()
        with self._cv:
            compare_decoded = self._instances.needs_decoding(instance, fingerprint)
        if compare_decoded:  # a copy sent before in another syntax: decoded here, not under the lock
            try:
                fingerprint = pixel_fingerprint(dataset, decode=True)
            except XRayObjectRejected as exc:
                return self._reject(exc.status, uid, sop_class, exc.reason)
        refused = None
        with self._cv:  # admitted and paired at once: a copy arriving meanwhile finds the frames paired
            try:
                new = self._instances.admit(instance, fingerprint)
            except XRayObjectRejected as exc:
                new, refused = False, exc
            if new:
                self._pair(frames, t0, now)
            elif refused is None:
                self._counts["objects_duplicate"] += 1
        if refused is not None:
            return self._reject(refused.status, uid, sop_class, refused.reason)
        if not new:
            log.info("received %s again (the same pixels): answered, not posed again", instance)
            return STATUS_SUCCESS
        log.info("received %s: %d frame(s) of plane(s) %s", uid, len(frames), sorted({f.view.name for f in frames}))
        return STATUS_SUCCESS

    def _pair(self, frames, t0: float, now: float) -> None:
        """Count an accepted object's frames, pair them and queue the completed pairs (the caller
        holds the lock)."""
        share = (now - t0) / len(frames)
        self._stats.decode_s += now - t0
        self._counts["objects_accepted"] += 1
        self._counts["frames_received"] += len(frames)
        if self._stats.t_first_frame is None:
            self._stats.t_first_frame = t0
        for f in frames:
            f = dataclasses.replace(f, decode_s=share, received_at=now)
            pairing = self.pairer.add(PlaneFrame(f.view.name, f.time_s, f.interval_s, data=f))
            for dropped in pairing.dropped:
                log.warning("frame %s[%d] of plane %r (%s) found no partner: dropped as unpaired",
                            dropped.data.instance_uid, dropped.data.frame_index, dropped.plane,
                            dropped.data.acquired.isoformat())
            self._counts["frames_unpaired"] += len(pairing.dropped)
            for pair in pairing.sets:
                self._enqueue(pair, now)
        self._cv.notify_all()

    def _enqueue(self, pair, now: float) -> None:
        """Queue a completed pair (the caller holds the lock)."""
        self._counts["pairs_completed"] += 1
        self._queue.append((self._first_index + self._counts["pairs_completed"] - 1, pair, now))
        if self.max_queued_pairs is not None and len(self._queue) > self.max_queued_pairs:
            index, skipped, _ = self._queue.popleft()
            self._counts["pairs_skipped"] += 1
            self._counts["pairs_dropped_stale"] += 1
            log.info("pair %d dropped for a newer one (max_queued_pairs=%d)", index, self.max_queued_pairs)
        self._counts["pairs_waiting_max"] = max(self._counts["pairs_waiting_max"], len(self._queue))

    def _reject(self, status: int, uid: str, sop_class: str, reason: str):
        log.warning("rejected object %s (SOP class %s) with status 0x%04X: %s", uid or "(no UID)", sop_class,
                    status, reason)
        with self._cv:
            self._stats.add_rejection(status, uid, sop_class, reason)
        return rejection_response(status, reason)

    # --- statistics -----------------------------------------------------------------------------

    def stats(self) -> dict:
        """Throughput and counts so far (a JSON-ready dict): the keys of
        :meth:`.receiver_counts.ReceiverCounts.stats`; ``tracker`` is :meth:`Tracker.stats`."""
        with self._cv:
            return self._stats.stats(n_views=len(self.views), pairs_waiting=len(self._queue), port=self.port,
                                     now=time.perf_counter())


def _dimse_recv_first(event) -> None:
    """Move the receiver's own EVT_DIMSE_RECV handler ahead of pynetdicom's logging one, which
    raises on a C-STORE command without a SOP class and so ends the handlers' loop before ours."""
    from pynetdicom import evt

    assoc = event.assoc
    bound = list(assoc.get_handlers(evt.EVT_DIMSE_RECV))
    ours = [h for h in bound if getattr(h[0], "__name__", "") == "_on_dimse_received"]
    if not ours or bound[0] is ours[0]:
        return
    for handler, _ in bound:
        assoc.unbind(evt.EVT_DIMSE_RECV, handler)
    for handler, args in ours + [h for h in bound if h not in ours]:
        assoc.bind(evt.EVT_DIMSE_RECV, handler, args)
