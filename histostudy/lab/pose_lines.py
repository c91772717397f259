"""The JSON line the live receiver writes per biplane pair (:func:`pose_line`, §II-A; its fields in
docs/receiver.md, "The pose line") and the file it appends them to (:class:`PoseLineFile`: whole
lines only, a run stopped or killed continued by the next).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

from histostudy.core import to_jsonable
from histostudy.pose import PoseResult, pose_record
from histostudy.transducer import TransducerModel

from .xray_objects import PendingFrame, ReceivedFrame

__all__ = ["PoseLineFile", "pose_line"]

log = logging.getLogger(__name__)


def pose_line(index: int, frames: Sequence[ReceivedFrame | PendingFrame], queued_at: float, taken_at: float, *,
              result: PoseResult | None, error: BaseException | None, tracking: str | None, t_free: float,
              t_written: float, model: TransducerModel | None = None) -> dict:
    """The JSON-ready line of pair ``index`` (module docstring): ``result``'s pose, or the ``error``
    its pose work raised (``result`` then None; ``frames`` may then be the pair's
    :class:`~.xray_objects.PendingFrame` objects, where their pixels raised); a ValueError where both
    are None. ``tracking``: the tracker's ``last_kind`` for the result. Times are
    ``time.perf_counter`` seconds: ``queued_at`` / ``taken_at`` (the pair queued / taken by the
    tracker), ``t_free`` (the worker's previous line written), ``t_written`` (now)."""
    ids = [f"{f.instance_uid}[{f.frame_index}]" for f in frames]
    record = {"pair_index": index, "planes": [f.view.name for f in frames],
              "instance_uids": [f.instance_uid for f in frames], "frame_indices": [f.frame_index for f in frames],
              "frame_times": [f.acquired.isoformat() for f in frames]}
    if error is None:
        if result is None:
            raise ValueError(f"pair {index}: result=None and error=None: expected its PoseResult, or the error "
                             "its pose work raised")
        record.update({**pose_record(result, ids, model=model), "tracking": tracking})
    else:
        record.update({"frames": ids, "accepted": False, "error": f"{type(error).__name__}: {error}",
                       "tracking": None})
    record["seconds"] = {"decode": sum(f.decode_s for f in frames), "queue": taken_at - queued_at,
                         "pose": t_written - max(taken_at, t_free),
                         "latency": t_written - max(f.received_at for f in frames)}
    return to_jsonable(record)


class PoseLineFile:
    """The JSON-lines file of a receiver's poses, appended a whole line at a time and continued
    across runs.

    Each line goes to the file in one ``write`` of an ``O_APPEND`` descriptor, so a process killed
    (even with SIGKILL) leaves whole lines, bar one torn by a kill inside that write, which
    :meth:`open` cuts off (logged) before the next run appends. :meth:`open` also reads where the
    last run stopped: its pairs are numbered on from there.

    Args:
        path: the file; created (honouring the umask) where it does not exist.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fd: int | None = None

    def next_index(self) -> int:
        """The index the next pair gets (:meth:`open`'s), read without creating or changing the file.

        Raises:
            ValueError: as :meth:`open`.
        """
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return 0
        try:
            return self._scan(fd)[0]
        finally:
            os.close(fd)

    def open(self) -> int:
        """Open for appending; cut off a torn last line.

        Returns:
            The next pair index: one past the last line's ``pair_index``, 0 for a new or empty file.

        Raises:
            OSError: the file cannot be opened (its path named).
            ValueError: the last whole line is not a pose line (no integer ``pair_index``): the file
                is not a receiver's; nothing is cut or written.
        """
        fd = os.open(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            next_index, torn = self._scan(fd)
            if torn:
                log.warning("%s ended in a torn line (%d bytes, a run killed while writing it): cut off",
                            self.path, torn)
                os.ftruncate(fd, os.fstat(fd).st_size - torn)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return next_index

    def _scan(self, fd: int) -> tuple[int, int]:
        """(the next pair index, the bytes of a torn last line) of the open file ``fd``."""
        tail, at = b"", os.fstat(fd).st_size
        while at > 0 and tail.count(b"\n") < 2:  # the last whole line, and a torn one after it
            step = min(at, 65536)
            at -= step
            tail = os.pread(fd, step, at) + tail
        whole_end = tail.rfind(b"\n") + 1  # 0: no whole line in the tail (nor, then, in the file)
        last = tail[:whole_end].rstrip(b"\n").rsplit(b"\n", 1)[-1]
        if not last:
            return 0, len(tail) - whole_end
        try:
            return int(json.loads(last)["pair_index"]) + 1, len(tail) - whole_end
        except (ValueError, KeyError, TypeError):
            raise ValueError(f"output_path {str(self.path)!r} holds lines that are not pose lines "
                             f"(its last: {last[:80]!r}); give a new file or a receiver's own") from None

    def append(self, record: dict) -> None:
        """Append ``record`` as one line; a write that fails (a full disk, a closed file) is logged,
        naming the file, and the stream goes on."""
        data = (json.dumps(record) + "\n").encode()
        try:
            if self._fd is None:
                raise ValueError("the file is not open")
            written = os.write(self._fd, data)
            if written != len(data):  # a full disk mid-line: the part written is cut off again
                os.ftruncate(self._fd, os.fstat(self._fd).st_size - written)
                raise OSError(f"{written} of {len(data)} bytes written")
        except (OSError, ValueError):
            log.exception("pair %s: the pose line could not be written to %s", record.get("pair_index"), self.path)

    def close(self) -> None:
        """Close the file (again: nothing)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
