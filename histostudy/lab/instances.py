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

__all__ = ["DIGEST_BYTES", "NATIVE_TRANSFER_SYNTAXES", "InstanceRegister", "PixelFingerprint", "pixel_fingerprint"]

#: Uncompressed little-endian transfer syntaxes (implicit, explicit, deflated explicit VR): their
#: PixelData bytes, as read, are the pixels themselves, so two objects in any of them compare byte
#: for byte (explicit VR big endian's 16-bit pixels are byte-swapped: compared after decoding).
NATIVE_TRANSFER_SYNTAXES = ("1.2.840.10008.1.2", "1.2.840.10008.1.2.1", "1.2.840.10008.1.2.1.99")
#: The size of a pixel digest (blake2b, bytes): 128 bits, no accidental collision in a procedure.
DIGEST_BYTES = 16


@dataclasses.dataclass(frozen=True)
class PixelFingerprint:
    """What tells two copies of one SOP instance apart: the pixel module's shape and a digest of
    its pixels, as sent (``encoded``: the transfer syntax and the PixelData bytes) and, where known,
    as decoded (``decoded``: the pixels' bytes, for a native syntax the PixelData itself).

    Attributes:
        shape: ``(frames, rows, columns, samples, bits allocated)``.
        transfer_syntax: the object's transfer syntax UID.
        encoded: blake2b (16 bytes) of the PixelData value as received.
        decoded: blake2b (16 bytes) of the decoded pixels (C order), None where not yet decoded.
    """

    shape: tuple
    transfer_syntax: str
    encoded: bytes
    decoded: bytes | None


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
    encoded = hashlib.blake2b(syntax.encode() + b"\0" + raw, digest_size=DIGEST_BYTES).digest()
    decoded = None
    if syntax in NATIVE_TRANSFER_SYNTAXES:
        frames, rows, cols, samples, bits = shape
        decoded = hashlib.blake2b(raw[:frames * rows * cols * samples * (bits // 8)], digest_size=DIGEST_BYTES).digest()
    elif decode:
        try:
            pixels = dataset.pixel_array
        except Exception as exc:  # noqa: BLE001 - pydicom's decoders raise several kinds
            raise XRayObjectRejected(STATUS_DATASET_MISMATCH, f"the pixels cannot be decoded to compare them with "
                                                              f"an earlier copy: {type(exc).__name__}: {exc}") from None
        decoded = hashlib.blake2b(pixels.tobytes(order="C"), digest_size=DIGEST_BYTES).digest()
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
        # each instance as one bytes value (its kind's index, its digests): a procedure's hundreds of
        # thousands of objects held in about 300 bytes each, UID included, not a kilobyte
        self._taken: OrderedDict[str, bytes] = OrderedDict()
        self._kinds: dict[tuple, int] = {}  # (shape, transfer syntax) -> its index in _kind_list
        self._kind_list: list[tuple] = []

    def _pack(self, fingerprint: PixelFingerprint) -> bytes:
        kind = (tuple(fingerprint.shape), str(fingerprint.transfer_syntax))
        index = self._kinds.get(kind)
        if index is None:
            index = self._kinds[kind] = len(self._kind_list)
            self._kind_list.append(kind)
        return index.to_bytes(4, "little") + fingerprint.encoded + (fingerprint.decoded or b"")

    def _unpack(self, value: bytes | None) -> PixelFingerprint | None:
        if value is None:
            return None
        shape, syntax = self._kind_list[int.from_bytes(value[:4], "little")]
        encoded, decoded = value[4:4 + DIGEST_BYTES], value[4 + DIGEST_BYTES:] or None
        return PixelFingerprint(shape, syntax, encoded, decoded)

    def __len__(self) -> int:
        return len(self._taken)

    def __contains__(self, uid: str) -> bool:
        return uid in self._taken

    def needs_decoding(self, uid: str, fingerprint: PixelFingerprint) -> bool:
        """Whether :meth:`admit` can tell ``uid`` apart only with ``fingerprint``'s decoded pixels
        (an earlier copy came in another transfer syntax): decode outside any lock, then admit."""
        earlier = self._unpack(self._taken.get(str(uid)))
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
        uid = str(uid)  # a plain str: pydicom's UID carries more
        earlier = self._unpack(self._taken.get(uid))
        if earlier is None:
            self._taken[uid] = self._pack(fingerprint)
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
