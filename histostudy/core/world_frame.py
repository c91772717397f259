"""The name of the world frame every position of the library and of the lab's files is in, and the
keys that state it in a JSON file (docs/architecture.md, "Frames and units"; §II-D), kept below
every layer so that the command line can name it without importing the imaging chain.
"""

from __future__ import annotations

__all__ = ["WORLD_FRAME", "world_frame_keys"]

#: The frame every position the library reads and the lab's commands write is in: the C-arm's,
#: which is the CBCT's world frame, with DICOM's LPS axes (+x towards the patient's left, +y
#: posterior, +z superior), in mm; transforms are ``T_<to>_<from>`` (4x4, mm), mapping points of
#: ``<from>`` into ``<to>``.
WORLD_FRAME = "C-arm (CBCT world), DICOM LPS, mm"


def world_frame_keys(**units: str) -> dict:
    """The keys that say a JSON file's frame and units, the shape every lab command's file carries.

    Args:
        **units: more units by quantity (e.g. ``angle="rad"``); length is always mm.

    Returns:
        ``{"frame": WORLD_FRAME, "units": {"length": "mm", **units}}``.

    Raises:
        ValueError: a unit that is not a non-empty string.
    """
    for name, unit in units.items():
        if not isinstance(unit, str) or not unit:
            raise ValueError(f"units: {name}={unit!r}, expected the unit's name (e.g. angle='rad')")
    return {"frame": WORLD_FRAME, "units": {"length": "mm", **units}}
