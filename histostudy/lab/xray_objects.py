"""Received DICOM X-ray objects checked and decoded into frames of line integrals, each with its plane
(§II-A): the header read and checked at once (:func:`read_xray_header`), the pixels converted only for
the pairs posed (:meth:`PendingFrame.decode`), and the C-STORE failure statuses of refused objects
(docs/receiver.md, "X-ray objects").
"""

from __future__ import annotations

import datetime as _dt
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from histostudy.imaging import View, line_integrals_from_pixels
from histostudy.imaging.io import (
    RECEIVABLE_TRANSFER_SYNTAXES,
    X_RAY_SOP_CLASSES,
    XRayObjectRejected,
    check_sop_class,
    check_xray_object,
    xray_pixels,
)

from .access import RECEIVER_MAX_PDU_BYTES
from .pairing import frame_times, posix_seconds

if TYPE_CHECKING:
    from pydicom.dataset import Dataset

__all__ = ["PendingFrame", "REJECTION_STATUSES", "ReceivedFrame", "VIEW_MATCH_TOLERANCE_MM", "X_RAY_SOP_CLASSES",
           "XRayObjectRejected", "decode_xray_object", "read_xray_header"]

log = logging.getLogger(__name__)

#: How far (mm at the isocentre) a frame's gantry tags may project from its plane's view before
#: the frame is refused as of another geometry: the receiver's ``match_tolerance_mm`` and the lab
#: commands' bound on ``--views`` against the files' tags.
VIEW_MATCH_TOLERANCE_MM = 5.0

STATUS_SUCCESS = 0x0000
STATUS_DUPLICATE_INSTANCE = 0x0111
STATUS_SOP_CLASS_NOT_SUPPORTED = 0x0122
STATUS_OUT_OF_RESOURCES = 0xA700
STATUS_DATASET_MISMATCH = 0xA900
STATUS_CANNOT_UNDERSTAND = 0xC000

#: The C-STORE failure statuses the receiver answers, and when (see the module docstring).
REJECTION_STATUSES = {
    STATUS_DUPLICATE_INSTANCE: "Refused: Duplicate SOP Instance (a UID received before with other pixels)",
    STATUS_SOP_CLASS_NOT_SUPPORTED: "Refused: SOP Class not supported (not an X-ray image)",
    STATUS_OUT_OF_RESOURCES: "Refused: Out of resources (the receiver is stopping)",
    STATUS_DATASET_MISMATCH: "Error: Data Set does not match SOP Class (unreadable X-ray object)",
    STATUS_CANNOT_UNDERSTAND: "Error: Cannot understand (missing geometry or time, or no matching view)",
}


@dataclass(frozen=True, eq=False)
class ReceivedFrame:
    """One decoded frame: ``image`` line integrals (float32, the view's shape) of plane ``view``,
    frame ``frame_index`` of the object ``instance_uid``, taken at ``acquired`` (its cine's interval
    ``interval_s``, None for a single frame). ``decode_s``: its share of the object's decoding time."""

    view: View
    image: np.ndarray = field(repr=False)
    instance_uid: str
    frame_index: int
    acquired: _dt.datetime
    interval_s: float | None
    decode_s: float = 0.0
    received_at: float = 0.0  # time.perf_counter() when decoded

    @property
    def time_s(self) -> float:
        return posix_seconds(self.acquired)


@dataclass(frozen=True, eq=False)
class PendingFrame:
    """One received frame whose header is checked (:func:`read_xray_header`) and whose pixels are not
    yet converted: plane ``view``, frame ``frame_index`` of the object ``instance_uid`` (its data set
    ``dataset``), taken at ``acquired`` (its cine's interval ``interval_s``, None for a single
    frame). ``decode_s``: its share of the object's header reading (s); ``received_at``:
    ``time.perf_counter()`` when read. :meth:`decode` gives the :class:`ReceivedFrame`."""

    view: View
    dataset: Dataset = field(repr=False)
    instance_uid: str
    frame_index: int
    acquired: _dt.datetime
    interval_s: float | None
    decode_s: float = 0.0
    received_at: float = 0.0

    @property
    def time_s(self) -> float:
        return posix_seconds(self.acquired)

    def decode(self, air_value: float | None = None) -> ReceivedFrame:
        """The frame with its pixels as line integrals (:func:`decode_xray_object`'s ``air_value``);
        only this frame's pixels are decoded. Its ``decode_s`` adds the seconds spent here.

        Raises:
            XRayObjectRejected: 0xA900, the pixels cannot be read (a compressed stream that does
                not decode); 0xC000, they cannot be used (a frame without signal).
        """
        t0 = time.perf_counter()
        ds = self.dataset
        rows, cols = int(ds.Rows), int(ds.Columns)
        pixels = xray_pixels(ds, self.frame_index)  # the decoder load_frame uses: 0xA900 if it fails
        try:
            image = line_integrals_from_pixels(pixels.reshape(1, rows, cols), ds, air_value=air_value)[0]
        except ValueError as exc:  # a frame without signal
            raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, str(exc).replace("frame 0 ", f"frame "
                                                                                 f"{self.frame_index} ")) from None
        return ReceivedFrame(view=self.view, image=image, instance_uid=self.instance_uid,
                             frame_index=self.frame_index, acquired=self.acquired, interval_s=self.interval_s,
                             decode_s=self.decode_s + time.perf_counter() - t0, received_at=self.received_at)


def read_xray_header(ds, views: Sequence[View], *, sop_class_uid: str | None = None,
                     match_tolerance_mm: float | None = VIEW_MATCH_TOLERANCE_MM) -> list[PendingFrame]:
    """The frames of one received DICOM X-ray object, each with its plane's view, checked as far as
    the header goes: the pixels are left for :meth:`PendingFrame.decode` (the receiver converts
    only the pairs it poses).

    Checks the SOP class, the image size, the geometry tags against ``views``, the frame times, the
    pixel module's tags (MONOCHROME1's ``BitsStored``, the rescale) and, for a native (not
    encapsulated) transfer syntax, that ``PixelData`` holds every frame's bytes. What only the
    pixels can tell (a compressed stream that does not decode, a frame without signal) is left to
    :meth:`PendingFrame.decode`. Arguments and refusals as :func:`decode_xray_object`'s.
    """
    # the checks load_frame applies to a file (histostudy pose, calibrate): the same objects refused alike
    check_xray_object(ds, sop_class_uid=str(getattr(ds, "SOPClassUID", "") or "") if sop_class_uid is None
                      else sop_class_uid)
    uid = str(getattr(ds, "SOPInstanceUID", "") or "")
    n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)  # bounded by check_xray_object (pixels, fragments)
    # the plane of each frame: once for a plain cine, per frame where functional groups may differ
    per_frame = bool(getattr(ds, "PerFrameFunctionalGroupsSequence", None))
    plane_views = []
    for i in range(n_frames if per_frame else 1):
        plane_views.append(_plane_view(ds, views, i if per_frame else None, match_tolerance_mm))
    if not per_frame:
        plane_views *= n_frames
    try:
        times, interval_s = frame_times(ds)
    except ValueError as exc:
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, str(exc)) from None
    _check_pixel_module(ds)
    return [PendingFrame(view=plane_views[i], dataset=ds, instance_uid=uid, frame_index=i, acquired=times[i],
                         interval_s=interval_s) for i in range(n_frames)]


def decode_xray_object(ds, views: Sequence[View], *, sop_class_uid: str | None = None, air_value: float | None = None,
                       match_tolerance_mm: float | None = 5.0) -> list[ReceivedFrame]:
    """The frames of one received DICOM X-ray object, each with its plane's view, its pixels as line
    integrals: :func:`read_xray_header` then :meth:`PendingFrame.decode` of every frame.

    Args:
        ds: the pydicom ``Dataset`` (with ``file_meta`` giving its transfer syntax).
        views: the planes' views (their names are the planes').
        sop_class_uid: the SOP class the sender said it stores (the C-STORE's affected SOP class);
            None: the data set's own.
        air_value: the unattenuated intensity ``I0`` of ``-log(I / I0)`` (modality units); None:
            each frame's maximum, as :func:`histostudy.imaging.load_frame`.
        match_tolerance_mm: the largest distance between the projections of the isocentre region
            (the isocentre and the corners of a 100 mm cube around it) by the tags' geometry and by
            a view, in mm at the isocentre (detector pixels times the view's pixel size there), for
            a frame to be that view's: 5 mm passes a gantry 1 deg off its calibrated angle (0.9
            mm) and refuses one 10 deg off (8.7 mm). None: a named plane is not checked and an
            unnamed one takes the nearest view.

    Raises:
        XRayObjectRejected: with the status to answer and why (module docstring).
    """
    return [frame.decode(air_value) for frame in read_xray_header(ds, views, sop_class_uid=sop_class_uid,
                                                                  match_tolerance_mm=match_tolerance_mm)]


def read_c_store(event, views: Sequence[View], *, match_tolerance_mm: float | None = 5.0) -> list[PendingFrame]:
    """The frames of a pynetdicom C-STORE request ``event``, header checked and pixels not converted
    (:func:`read_xray_header`): what the receiver's handler needs to answer and to pair. A SOP class
    that is not an X-ray image is refused before its data set is decoded, and an unforeseen error in
    a sender's object becomes a refusal (0xC000), logged, so that the receiver keeps serving. Raises
    :class:`XRayObjectRejected` only."""
    sop_class = str(getattr(event.request, "AffectedSOPClassUID", "") or "")
    check_sop_class(sop_class, stored=sop_class)  # the reason load_frame gives for the same object
    try:
        ds = event.dataset
        ds.file_meta = event.file_meta
    except Exception as exc:  # pydicom raises several kinds for an undecodable data set
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"the data set cannot be decoded: "
                                                          f"{type(exc).__name__}: {exc}") from None
    try:
        return read_xray_header(ds, views, sop_class_uid=sop_class, match_tolerance_mm=match_tolerance_mm)
    except XRayObjectRejected:
        raise
    except Exception as exc:
        log.exception("unexpected error reading object %s", getattr(event.request, "AffectedSOPInstanceUID", ""))
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, f"{type(exc).__name__}: {exc}") from None


def decode_c_store(event, views: Sequence[View], *, air_value: float | None = None,
                   match_tolerance_mm: float | None = 5.0) -> list[ReceivedFrame]:
    """The frames of a pynetdicom C-STORE request ``event`` with their pixels as line integrals:
    :func:`read_c_store` then :meth:`PendingFrame.decode` of every frame. Raises
    :class:`XRayObjectRejected` only."""
    return [frame.decode(air_value) for frame in read_c_store(event, views, match_tolerance_mm=match_tolerance_mm)]


def rejection_response(status: int, reason: str):
    """The C-STORE response dataset of a refusal: ``Status`` and the reason as ``ErrorComment``
    (LO: its first 64 characters)."""
    from pydicom.dataset import Dataset

    response = Dataset()
    response.Status = int(status)
    response.ErrorComment = reason[:64]
    return response


def storage_application_entity(ae_title: str, network_timeout_s: float):
    """pynetdicom's application entity of a Storage SCP that C-arms send X-ray objects to: every
    storage SOP class accepted at negotiation, so that an object that is not an X-ray image reaches
    the C-STORE handler and gets a failure status naming why (:func:`rejection_response`), and
    Verification (C-ECHO, the C-arm's connection test). Each storage context accepts the transfer
    syntaxes the readers decode (:data:`histostudy.imaging.io.RECEIVABLE_TRANSFER_SYNTAXES`: native,
    JPEG Lossless, JPEG-LS, JPEG 2000, RLE), so that a C-arm may send its frames compressed."""
    from pynetdicom import AE, AllStoragePresentationContexts
    from pynetdicom.sop_class import Verification  # type: ignore[attr-defined]  # made at import, by globals()

    ae = AE(ae_title=ae_title)
    for context in AllStoragePresentationContexts:
        assert context.abstract_syntax is not None
        ae.add_supported_context(context.abstract_syntax, list(RECEIVABLE_TRANSFER_SYNTAXES))
    ae.add_supported_context(Verification)
    # an idle association, and a connection that sends no A-ASSOCIATE-RQ (its thread waits for one)
    ae.network_timeout = ae.acse_timeout = network_timeout_s
    # a frame in a few P-DATA PDUs (access.RECEIVER_MAX_PDU_BYTES: why, and the guard's bound on any PDU)
    ae.maximum_pdu_size = RECEIVER_MAX_PDU_BYTES
    return ae


def _check_pixel_module(ds) -> None:
    """Refuses an object whose pixels could not be converted, as far as the tags tell: the tags
    :func:`histostudy.imaging.line_integrals_from_pixels` reads (0xC000), as load_frame reads them."""
    try:
        line_integrals_from_pixels(np.ones((1, 1)), ds, air_value=1.0)  # the tags alone: a one-pixel probe
    except ValueError as exc:
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, str(exc)) from None


def _plane_view(ds, views: Sequence[View], frame_index: int | None, tol_mm: float | None) -> View:
    """The view of a frame: named by SeriesDescription (and confirmed by the tags), else matched by
    the geometry the tags record."""
    try:
        tag_view = View.from_dicom(ds, frame_index=frame_index)
    except ValueError as exc:
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, f"its geometry cannot be read: {exc}") from None
    description = str(getattr(ds, "SeriesDescription", "") or "").strip()
    named = [v for v in views if v.name and v.name == description]
    if named:
        view = named[0]
        if tag_view.shape != view.shape:
            raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND,
                                     f"plane {description!r}: its {tag_view.shape[0]} x {tag_view.shape[1]} pixels "
                                     f"differ from view {view.name!r}'s {view.shape}")
        if tol_mm is not None:
            distance = tag_view.projection_distance_mm(view)
            if distance > tol_mm:
                raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND,
                                         f"plane {description!r}: its geometry tags project {distance:.1f} mm (at the "
                                         f"isocentre) from view {view.name!r} (> {tol_mm} mm); has the gantry moved "
                                         "since the views were calibrated?")
        return view
    candidates = sorted(((tag_view.projection_distance_mm(v), i) for i, v in enumerate(views)
                         if v.shape == tag_view.shape))
    if candidates and (tol_mm is None or candidates[0][0] <= tol_mm):
        return views[candidates[0][1]]
    nearest = f"; the nearest view is {candidates[0][0]:.1f} mm off (> {tol_mm} mm)" if candidates else \
        f"; no view has its {tag_view.shape} pixels"
    raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND,
                             f"it matches no view: SeriesDescription {description!r} names none of "
                             f"{[v.name for v in views]}{nearest}")


