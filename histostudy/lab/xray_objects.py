"""Received DICOM X-ray objects decoded and checked: frames of line integrals, each with its plane (§II-A).

What the live receiver (:mod:`.receiver`) does with each object a C-arm or a PACS sends it, before
any pairing or pose: :func:`decode_xray_object` checks the SOP class, the geometry tags, the frame
times and the pixels, and gives one :class:`ReceivedFrame` per frame (a cine's frames each one);
:func:`decode_c_store` runs it on a pynetdicom C-STORE request and :func:`rejection_response` is
the answer to a refused one.

- **The plane.** Each frame goes to a plane (a view): the view named as the object's
  ``SeriesDescription`` — whose geometry the tags (:meth:`histostudy.imaging.View.from_dicom`) must
  confirm within ``match_tolerance_mm``, so that a gantry moved since the views were calibrated is
  refused, not silently mis-posed — else the view the tags' geometry matches. Two views are
  compared by their projections of the isocentre region (the isocentre and the corners of a 100 mm
  cube around it), in mm at the isocentre.
- **The times.** ``AcquisitionDateTime`` plus frame index x ``FrameTime`` (:func:`.pairing.frame_times`).
- **The pixels.** Line integrals ``-log(I / I0)`` by :func:`histostudy.imaging.line_integrals_from_pixels`,
  as :func:`histostudy.imaging.load_frame` makes them (MONOCHROME1 inverted, rescale applied, ``I0``
  = ``air_value`` or the frame's maximum).

Refusals raise :class:`XRayObjectRejected` with the C-STORE failure status to answer
(:data:`REJECTION_STATUSES`):

- ``0x0122`` Refused: SOP Class not supported — not an X-ray image (e.g. CT Image Storage).
- ``0xA900`` Error: Data Set does not match SOP Class — an X-ray object that cannot be read as
  one: undecodable, pixel data of the wrong length, the data set's SOP class differing from the
  request's.
- ``0xC000`` Error: Cannot understand — a readable X-ray object that cannot be used: missing
  geometry tags, no acquisition time, colour pixels, a bad rescale, a frame without signal, a plane
  matching no view.
- ``0xA700`` Refused: Out of resources — the receiver is stopping (answered by the receiver).

Units: mm, seconds; frames and transforms as in docs/architecture.md.
"""

from __future__ import annotations

import datetime as _dt
import logging
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from histostudy.imaging import View, line_integrals_from_pixels
from .pairing import frame_times, posix_seconds

__all__ = ["REJECTION_STATUSES", "ReceivedFrame", "X_RAY_SOP_CLASSES", "XRayObjectRejected", "decode_xray_object"]

log = logging.getLogger(__name__)

#: The SOP classes whose frames are received (the others are answered 0x0122).
X_RAY_SOP_CLASSES = {
    "1.2.840.10008.5.1.4.1.1.12.1": "X-Ray Angiographic Image Storage",
    "1.2.840.10008.5.1.4.1.1.12.1.1": "Enhanced XA Image Storage",
    "1.2.840.10008.5.1.4.1.1.12.2": "X-Ray Radiofluoroscopic Image Storage",
}

STATUS_SUCCESS = 0x0000
STATUS_SOP_CLASS_NOT_SUPPORTED = 0x0122
STATUS_OUT_OF_RESOURCES = 0xA700
STATUS_DATASET_MISMATCH = 0xA900
STATUS_CANNOT_UNDERSTAND = 0xC000

#: The C-STORE failure statuses the receiver answers, and when (see the module docstring).
REJECTION_STATUSES = {
    STATUS_SOP_CLASS_NOT_SUPPORTED: "Refused: SOP Class not supported (not an X-ray image)",
    STATUS_OUT_OF_RESOURCES: "Refused: Out of resources (the receiver is stopping)",
    STATUS_DATASET_MISMATCH: "Error: Data Set does not match SOP Class (unreadable X-ray object)",
    STATUS_CANNOT_UNDERSTAND: "Error: Cannot understand (missing geometry or time, or no matching view)",
}

#: Test points (mm, C-arm frame) whose projections compare two views: the isocentre and the
#: corners of a 100 mm cube around it, the region where the transducer's focal point is sought.
_PROBE_POINTS_MM = np.array([[0.0, 0.0, 0.0]] + [[x, y, z] for x in (-50.0, 50.0) for y in (-50.0, 50.0)
                                                 for z in (-50.0, 50.0)])


class XRayObjectRejected(ValueError):
    """A received object the receiver refuses: ``status`` is the C-STORE failure status to answer
    (:data:`REJECTION_STATUSES`), the message the reason."""

    def __init__(self, status: int, reason: str):
        super().__init__(reason)
        self.status = int(status)
        self.reason = reason


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


def decode_xray_object(ds, views: Sequence[View], *, sop_class_uid: str | None = None, air_value: float | None = None,
                       match_tolerance_mm: float | None = 5.0) -> list[ReceivedFrame]:
    """The frames of one received DICOM X-ray object, each with its plane's view.

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
    sop = str(getattr(ds, "SOPClassUID", "") or "")
    expected = sop if sop_class_uid is None else str(sop_class_uid)
    if expected not in X_RAY_SOP_CLASSES:
        raise XRayObjectRejected(STATUS_SOP_CLASS_NOT_SUPPORTED,
                                 f"SOP class {expected or '(none)'} is not an X-ray angiographic or RF image; "
                                 f"this receiver takes {', '.join(X_RAY_SOP_CLASSES.values())}")
    if sop != expected:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"the data set's SOPClassUID {sop or '(none)'} differs from the stored SOP class "
                                 f"{expected}")
    uid = str(getattr(ds, "SOPInstanceUID", "") or "")
    try:
        n_frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
        rows, cols = int(ds.Rows), int(ds.Columns)
    except (AttributeError, TypeError, ValueError) as exc:
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"no readable image size (Rows, Columns, "
                                                          f"NumberOfFrames): {exc}") from None
    samples = int(getattr(ds, "SamplesPerPixel", 1) or 1)
    if samples != 1:
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, f"SamplesPerPixel (0028,0002) is {samples}; X-ray "
                                                           "frames must be greyscale (1)")
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
    try:
        pixels = np.asarray(ds.pixel_array)
    except Exception as exc:  # pydicom raises several kinds for a broken pixel module
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH,
                                 f"its pixel data cannot be read: {type(exc).__name__}: {exc}") from None
    pixels = pixels.reshape((n_frames, rows, cols)) if pixels.size == n_frames * rows * cols else pixels
    if pixels.shape != (n_frames, rows, cols) and not (n_frames == 1 and pixels.shape == (rows, cols)):
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"its pixel data decode to shape {pixels.shape}, not "
                                                          f"{n_frames} frames of {rows} x {cols}")
    try:
        images = line_integrals_from_pixels(pixels.reshape(n_frames, rows, cols), ds, air_value=air_value)
    except ValueError as exc:  # a bad rescale tag, a frame without signal
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, str(exc)) from None
    return [ReceivedFrame(view=plane_views[i], image=images[i], instance_uid=uid, frame_index=i, acquired=times[i],
                          interval_s=interval_s) for i in range(n_frames)]


def decode_c_store(event, views: Sequence[View], **options) -> list[ReceivedFrame]:
    """The frames of a pynetdicom C-STORE request ``event`` (:func:`decode_xray_object` with
    ``options``): a SOP class that is not an X-ray image is refused before its data set is decoded,
    and an unforeseen error in a sender's object becomes a refusal (0xC000), logged, so that the
    receiver keeps serving. Raises :class:`XRayObjectRejected` only."""
    sop_class = str(getattr(event.request, "AffectedSOPClassUID", "") or "")
    if sop_class not in X_RAY_SOP_CLASSES:
        raise XRayObjectRejected(STATUS_SOP_CLASS_NOT_SUPPORTED,
                                 f"SOP class {sop_class} is not an X-ray angiographic or RF image")
    try:
        ds = event.dataset
        ds.file_meta = event.file_meta
    except Exception as exc:  # pydicom raises several kinds for an undecodable data set
        raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"the data set cannot be decoded: "
                                                          f"{type(exc).__name__}: {exc}") from None
    try:
        return decode_xray_object(ds, views, sop_class_uid=sop_class, **options)
    except XRayObjectRejected:
        raise
    except Exception as exc:
        log.exception("unexpected error decoding object %s", getattr(event.request, "AffectedSOPInstanceUID", ""))
        raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND, f"{type(exc).__name__}: {exc}") from None


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
    Verification (C-ECHO, the C-arm's connection test)."""
    from pynetdicom import AE, AllStoragePresentationContexts
    from pynetdicom.sop_class import Verification

    ae = AE(ae_title=ae_title)
    for context in AllStoragePresentationContexts:
        ae.add_supported_context(context.abstract_syntax)
    ae.add_supported_context(Verification)
    ae.network_timeout = network_timeout_s
    return ae


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
            distance = _projection_distance_mm(tag_view, view)
            if distance > tol_mm:
                raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND,
                                         f"plane {description!r}: its geometry tags project {distance:.1f} mm (at the "
                                         f"isocentre) from view {view.name!r} (> {tol_mm} mm); has the gantry moved "
                                         "since the views were calibrated?")
        return view
    candidates = sorted(((_projection_distance_mm(tag_view, v), i) for i, v in enumerate(views)
                         if v.shape == tag_view.shape))
    if candidates and (tol_mm is None or candidates[0][0] <= tol_mm):
        return views[candidates[0][1]]
    nearest = f"; the nearest view is {candidates[0][0]:.1f} mm off (> {tol_mm} mm)" if candidates else \
        f"; no view has its {tag_view.shape} pixels"
    raise XRayObjectRejected(STATUS_CANNOT_UNDERSTAND,
                             f"it matches no view: SeriesDescription {description!r} names none of "
                             f"{[v.name for v in views]}{nearest}")


def _projection_distance_mm(a: View, b: View) -> float:
    """The largest distance between the two views' projections of the isocentre region, in mm at
    the isocentre (pixels times the size of ``b``'s pixel there), so that one tolerance serves
    any detector resolution."""
    px = float(np.max(np.linalg.norm(a.project(_PROBE_POINTS_MM) - b.project(_PROBE_POINTS_MM), axis=1)))
    return px * float(np.sqrt(b.pixel_footprint_mm2(np.zeros(3))[0]))
