"""Tests of histostudy.lab.pose_line: the receiver's JSON line per biplane pair."""

import datetime
import json
from types import SimpleNamespace

from histostudy.lab.pose_lines import pose_line


def _frame(plane: str, index: int, received_at: float):
    return SimpleNamespace(instance_uid=f"1.2.{plane}", frame_index=index, view=SimpleNamespace(name=plane),
                           acquired=datetime.datetime(2026, 11, 25, 12, 0, index), decode_s=0.25,
                           received_at=received_at)


def test_an_error_line_names_the_error_and_its_seconds_add_up():
    frames = [_frame("A", 3, 10.0), _frame("B", 3, 10.5)]
    line = pose_line(7, frames, queued_at=10.5, taken_at=11.0, result=None, error=ValueError("no feature"),
                     tracking="warm", t_free=11.5, t_written=12.0)
    assert json.loads(json.dumps(line)) == line  # JSON-ready
    assert line["pair_index"] == 7 and line["planes"] == ["A", "B"] and line["accepted"] is False
    assert line["error"] == "ValueError: no feature" and line["tracking"] is None
    assert line["frames"] == ["1.2.A[3]", "1.2.B[3]"] and line["frame_times"][0] == "2026-11-25T12:00:03"
    # decode summed over the frames; pose from the later of taken and the previous line; latency from the last frame
    assert line["seconds"] == {"decode": 0.5, "queue": 0.5, "pose": 0.5, "latency": 1.5}
