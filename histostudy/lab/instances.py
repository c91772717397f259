"""The SOP instances a receiver has taken, so that one sent again is answered and not posed twice
(a C-arm repeats a C-STORE whose response it lost): :class:`InstanceRegister` over each object's
:func:`pixel_fingerprint`. What counts as the same object is in docs/receiver.md, "An object sent again".
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import OrderedDict

from histostudy.core.checks import check_count

from .xray_objects import STATUS_DUPLICATE_INSTANCE, XRayObjectRejected

__all__ = ["NATIVE_TRANSFER_SYNTAXES", "InstanceRegister", "PixelFingerprint", "pixel_fingerprint"]

#: Uncompressed little-endian transfer syntaxes (implicit, explicit, deflated explicit VR): their
#: PixelData bytes, as read, are the pixels themselves, so two objects in any of them compare byte
#: for byte (explicit VR big endian's 16-bit pixels are byte-swapped: compared after decoding).
NATIVE_TRANSFER_SYNTAXES = ("1.2.840.10008.1.2", "1.2.840.10008.1.2.1", "1.2.840.10008.1.2.1.99")


@dataclasses.dataclass(frozen=True)
class PixelFingerprint:
    """What tells two copies of one SOP instance apart: the pixel module's shape and a digest of
    its pixels, as sent (``encoded``: the transfer syntax and the PixelData bytes) and, where known,
    as decoded (``decoded``: the pixels' bytes, for a native syntax the PixelData itself).

    Attributes:
        shape: ``(frames, rows, columns, samples, bits allocated)``.
        transfer_syntax: the object's transfer syntax UID.
        encoded: blake2b of the PixelData value as received.
        decoded: blake2b of the decoded pixels (C order), None where not yet decoded.
    """

    shape: tuple
    transfer_syntax: str
    encoded: str
    decoded: str | None


def pixel_fingerprint(dataset, *, decode: bool = False) -> PixelFingerprint:
    """The :class:`PixelFingerprint` of a received X-ray data set.

    Args:
        dataset: a pydicom Dataset with its ``file_meta`` (the receiver's, header already checked).
        decode: also decode compressed pixels (pydicom's ``pixel_array``) to fill ``decoded``; a
            native syntax's is its PixelData and needs no decoding.

    Returns:
        The fingerprint.

    Raises:
        XRayObjectRejected: 0xA900 (``STATUS_DATASET_MISMATCH``) where the pixels are wanted decoded
            and cannot be.
    """
    from .xray_objects import STATUS_DATASET_MISMATCH

    shape = (int(getattr(dataset, "NumberOfFrames", 1) or 1), int(dataset.Rows), int(dataset.Columns),
             int(getattr(dataset, "SamplesPerPixel", 1) or 1), int(dataset.BitsAllocated))
    syntax = str(dataset.file_meta.TransferSyntaxUID)
    raw = bytes(dataset.PixelData)
    encoded = hashlib.blake2b(syntax.encode() + b"\0" + raw, digest_size=20).hexdigest()
    decoded = None
    if syntax in NATIVE_TRANSFER_SYNTAXES:
        frames, rows, cols, samples, bits = shape
        decoded = hashlib.blake2b(raw[:frames * rows * cols * samples * (bits // 8)], digest_size=20).hexdigest()
    elif decode:
        try:
            pixels = dataset.pixel_array
        except Exception as exc:  # noqa: BLE001 - pydicom's decoders raise several kinds
            raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"the pixels cannot be decoded to compare them with "
                                                              f"an earlier copy: {type(exc).__name__}: {exc}") from None
        decoded = hashlib.blake2b(pixels.tobytes(order="C"), digest_size=20).hexdigest()
    return PixelFingerprint(shape, syntax, encoded, decoded)


class InstanceRegister:
    """The SOP instances taken so far, by SOP Instance UID, the ``max_instances`` most recent kept.

    :meth:`admit` tells a new instance from one taken before with the same pixels (a duplicate: to
    be answered success and not posed again) and refuses one taken before with other pixels (a
    sender reusing a UID: status 0x0111, Duplicate SOP Instance). Not thread-safe: the receiver
    calls it under its lock.

    Args:
        max_instances: how many instances are remembered (an integer >= 1); an instance older than
            that is taken as new if it comes again.

    Raises:
        ValueError: ``max_instances`` is not an integer >= 1.
    """

    def __init__(self, max_instances: int = 200_000):
        self.max_instances = check_count(max_instances, "max_instances")
        self._taken: OrderedDict[str, PixelFingerprint] = OrderedDict()

    def __len__(self) -> int:
        return len(self._taken)

    def __contains__(self, uid: str) -> bool:
        return uid in self._taken

    def needs_decoding(self, uid: str, fingerprint: PixelFingerprint) -> bool:
        """Whether :meth:`admit` can tell ``uid`` apart only with ``fingerprint``'s decoded pixels
        (an earlier copy came in another transfer syntax): decode outside any lock, then admit."""
        earlier = self._taken.get(uid)
        return (earlier is not None and fingerprint.decoded is None and earlier.decoded is not None
                and earlier.transfer_syntax != fingerprint.transfer_syntax)

    def admit(self, uid: str, fingerprint: PixelFingerprint) -> bool:
        """Record instance ``uid`` with its ``fingerprint``, or recognise it.

        Args:
            uid: the SOP Instance UID.
            fingerprint: its :func:`pixel_fingerprint` (decoded where :meth:`needs_decoding` says).

        Returns:
            True for a new instance (now recorded), False for a duplicate of one taken before.

        Raises:
            XRayObjectRejected: 0x0111 (``STATUS_DUPLICATE_INSTANCE``), ``uid`` was taken before with
                other pixels, or in another transfer syntax whose pixels were not compared; the
                reason names the UID and what differs.
        """
        earlier = self._taken.get(uid)
        if earlier is None:
            self._taken[uid] = fingerprint
            while len(self._taken) > self.max_instances:
                self._taken.popitem(last=False)
            return True
        self._taken.move_to_end(uid)
        if earlier.shape != fingerprint.shape:
            raise XRayObjectRejected(STATUS_DUPLICATE_INSTANCE, f"SOP instance {uid} was received before with "
                                                                f"another pixel shape {earlier.shape}")
        if earlier.transfer_syntax == fingerprint.transfer_syntax:
            same = earlier.encoded == fingerprint.encoded
        elif earlier.decoded is None or fingerprint.decoded is None:
            raise XRayObjectRejected(STATUS_DUPLICATE_INSTANCE,
                                     f"SOP instance {uid} was received before in transfer syntax "
                                     f"{earlier.transfer_syntax}; its pixels cannot be compared with these "
                                     f"({fingerprint.transfer_syntax})")
        else:
            same = earlier.decoded == fingerprint.decoded
        if not same:
            raise XRayObjectRejected(STATUS_DUPLICATE_INSTANCE,
                                     f"SOP instance {uid} was received before with other pixels")
        return False
