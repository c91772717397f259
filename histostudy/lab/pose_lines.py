"""The JSON line the live receiver writes per biplane pair (:func:`pose_line`, §II-A; its fields in
docs/receiver.md, "The pose line").
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence

from histostudy.core import to_jsonable
from histostudy.pose import PoseResult, pose_record
from histostudy.transducer import TransducerModel

from .xray_objects import ReceivedFrame

__all__ = ["pose_line"]

log = logging.getLogger(__name__)


def pose_line(index: int, frames: Sequence[ReceivedFrame], queued_at: float, taken_at: float, *,
              result: PoseResult | None, error: BaseException | None, tracking: str | None, t_free: float,
              t_written: float, model: TransducerModel | None = None) -> dict:
    """The JSON-ready line of pair ``index`` (module docstring): ``result``'s pose, or the ``error``
    its pose work raised (``result`` then None). ``tracking``: the tracker's ``last_kind`` for the
    result. Times are ``time.perf_counter`` seconds: ``queued_at`` / ``taken_at`` (the pair queued /
    taken by the tracker), ``t_free`` (the worker's previous line written), ``t_written`` (now)."""
    ids = [f"{f.instance_uid}[{f.frame_index}]" for f in frames]
    record = {"pair_index": index, "planes": [f.view.name for f in frames],
              "instance_uids": [f.instance_uid for f in frames], "frame_indices": [f.frame_index for f in frames],
              "frame_times": [f.acquired.isoformat() for f in frames]}
    if error is None:
        record.update({**pose_record(result, ids, model=model), "tracking": tracking})
    else:
        record.update({"frames": ids, "accepted": False, "error": f"{type(error).__name__}: {error}",
                       "tracking": None})
    record["seconds"] = {"decode": sum(f.decode_s for f in frames), "queue": taken_at - queued_at,
                         "pose": t_written - max(taken_at, t_free),
                         "latency": t_written - max(f.received_at for f in frames)}
    return to_jsonable(record)


def append_pose_line(out, record: dict, path) -> None:
    """Appends ``record`` (a :func:`pose_line`) to the open text file ``out`` as one JSON line and flushes
    it; a write that fails (a full disk, a closed file) is logged, naming ``path``, and the stream goes on."""
    try:
        out.write(json.dumps(record) + "\n")
        out.flush()
    except (OSError, ValueError):
        log.exception("pair %s: the pose line could not be written to %s", record.get("pair_index"), path)
