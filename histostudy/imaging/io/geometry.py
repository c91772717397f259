"""The C-arm geometry a DICOM XA or RF object records, read for a view (§II-A): positioner angles (deg),
source distances and the detector pitch (mm), and the image size (pixels). The angle conventions:
docs/imaging.md, "X-ray objects"."""

from __future__ import annotations

import math

__all__ = ["REQUIRED_GEOMETRY_TAGS", "gantry_from_dicom"]

#: The attributes a view needs, with their DICOM tags (for the error that names a missing one).
REQUIRED_GEOMETRY_TAGS = {
    "PositionerPrimaryAngle": "(0018,1510)",
    "PositionerSecondaryAngle": "(0018,1511)",
    "DistanceSourceToDetector": "(0018,1110)",
    "DistanceSourceToPatient": "(0018,1111)",
    "ImagerPixelSpacing": "(0018,1164)",
    "Rows": "(0028,0010)",
    "Columns": "(0028,0011)",
}


def _frame_groups(ds, frame_index: int | None) -> list:
    """The datasets to search for a frame's geometry: its per-frame functional group items (enhanced
    XA), then the shared functional groups, then the object's top level."""
    sources = []
    per_frame = getattr(ds, "PerFrameFunctionalGroupsSequence", None)
    if per_frame:
        if frame_index is None:
            frame_index = 0
        if not 0 <= frame_index < len(per_frame):
            raise ValueError(f"frame_index must be in [0, {len(per_frame)}) for this {len(per_frame)}-frame "
                             f"object, got {frame_index!r}")
        sources.append(per_frame[frame_index])
    shared = getattr(ds, "SharedFunctionalGroupsSequence", None)
    if shared:
        sources.append(shared[0])
    sources.append(ds)
    return sources


def _find(sources: list, keyword: str):
    """The first value of ``keyword`` in ``sources``, looking one sequence level deep as well
    (functional groups nest the attributes in macros such as PositionerPositionSequence)."""
    for item in sources:
        value = getattr(item, keyword, None)
        if value is not None:
            return value
        for element in item:
            if getattr(element, "VR", None) == "SQ" and element.value:
                value = getattr(element.value[0], keyword, None)
                if value is not None:
                    return value
    return None


def _number(value, keyword: str, source: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {keyword} {REQUIRED_GEOMETRY_TAGS.get(keyword, '')} must be a number, "
                         f"got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{source}: {keyword} must be finite, got {value!r}")
    return number


def gantry_from_dicom(ds, frame_index: int | None = None, source: str = "the DICOM object") -> dict:
    """The view parameters a DICOM XA/RF object records for one frame (§II-A).

    A rotational acquisition (``PositionerPrimaryAngleIncrement``) is refused: the standard leaves it
    open whether its increments are per frame or cumulative, and a wrong guess moves every view. An
    object of a SOP class that is not an X-ray image (CT, secondary capture, ...) is refused first,
    as every reader of the lab's frames refuses it (:func:`~.xray.check_sop_class`; a data set
    without SOPClassUID is refused where its file meta names the class it was stored as, and read as
    a bare set of tags where nothing does: :func:`~.xray.stored_sop_class`).

    Args:
        ds: the pydicom data set.
        frame_index: the frame whose functional groups (in an enhanced object) to read, an integer
            >= 0, or None.
        source: what the messages call the object.

    Returns:
        ``primary_deg``, ``secondary_deg`` (deg), ``source_isocenter_mm``, ``source_detector_mm``
        (mm), ``shape`` ``(rows, cols)`` (pixels) and ``pixel_mm`` ``(row spacing, column spacing)``
        (mm).

    Raises:
        XRayObjectRejected: the object is not an X-ray image.
        ValueError: ``frame_index`` invalid, a rotational acquisition, or an attribute missing or out
            of range (the message names it and its tag).
    """
    from .xray import check_sop_class, stored_sop_class

    check_sop_class(getattr(ds, "SOPClassUID", None), stored=stored_sop_class(ds), source=source)
    if frame_index is not None and (isinstance(frame_index, bool) or not isinstance(frame_index, int)
                                    or frame_index < 0):
        raise ValueError(f"frame_index must be an integer >= 0 or None, got {frame_index!r}")
    if getattr(ds, "PositionerPrimaryAngleIncrement", None) is not None:
        raise ValueError(f"{source} is a rotational acquisition (PositionerPrimaryAngleIncrement (0018,1520)); "
                         "its per-frame angles are not read yet: give its views in a views file, made from the "
                         "C-arm's calibration")
    sources = _frame_groups(ds, frame_index)
    values = {}
    for keyword, tag in REQUIRED_GEOMETRY_TAGS.items():
        value = _find(sources, keyword)
        if value is None:
            raise ValueError(f"{source} lacks {keyword} {tag}, which a view needs; give the frame's view in a "
                             "views file instead")
        values[keyword] = value
    spacing = values["ImagerPixelSpacing"]
    try:
        row_mm, col_mm = (_number(s, "ImagerPixelSpacing", source) for s in spacing)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: ImagerPixelSpacing (0018,1164) must be two numbers (row, column) in mm, "
                         f"got {spacing!r}") from exc
    primary_deg = _number(values["PositionerPrimaryAngle"], "PositionerPrimaryAngle", source)
    secondary_deg = _number(values["PositionerSecondaryAngle"], "PositionerSecondaryAngle", source)
    source_isocenter_mm = _number(values["DistanceSourceToPatient"], "DistanceSourceToPatient", source)
    source_detector_mm = _number(values["DistanceSourceToDetector"], "DistanceSourceToDetector", source)
    out = {
        "primary_deg": primary_deg,
        "secondary_deg": secondary_deg,
        "source_isocenter_mm": source_isocenter_mm,
        "source_detector_mm": source_detector_mm,
        "shape": (int(values["Rows"]), int(values["Columns"])),
        "pixel_mm": (row_mm, col_mm),
    }
    if not 0 < source_isocenter_mm < source_detector_mm:
        raise ValueError(f"{source}: DistanceSourceToDetector (0018,1110) {source_detector_mm} mm must exceed "
                         f"DistanceSourceToPatient (0018,1111) {source_isocenter_mm} mm, both > 0")
    if not (row_mm > 0 and col_mm > 0):
        raise ValueError(f"{source}: ImagerPixelSpacing (0018,1164) must be > 0 mm, got {spacing!r}")
    return out
