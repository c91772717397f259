"""Tests of histostudy.lab.pose_lines: the receiver's JSON line per biplane pair, and the file of
them, whole lines only and continued across runs, a run killed with SIGKILL included."""

import datetime
import json
import os
import signal
import stat
import time
from types import SimpleNamespace

import numpy as np
import pytest

from histostudy.lab.pose_lines import PoseLineFile, pose_line


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


def _records(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_file_is_created_under_the_umask_and_continued_by_the_next_run(tmp_path):
    path = tmp_path / "poses.jsonl"
    assert PoseLineFile(path).next_index() == 0 and not path.exists()  # read without creating
    old = os.umask(0o027)
    try:
        first = PoseLineFile(path)
        assert first.open() == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    for i in range(3):
        first.append({"pair_index": i, "accepted": True})
    first.close()
    first.close()  # again: nothing
    second = PoseLineFile(path)
    assert second.next_index() == 3 and second.open() == 3
    second.append({"pair_index": 3})
    second.close()
    assert [r["pair_index"] for r in _records(path)] == [0, 1, 2, 3]


def test_a_torn_last_line_is_cut_off_and_a_file_of_other_lines_is_refused(tmp_path, caplog):
    path = tmp_path / "poses.jsonl"
    path.write_text(json.dumps({"pair_index": 0}) + "\n" + json.dumps({"pair_index": 1}) + "\n" + '{"pair_in')
    out = PoseLineFile(path)
    assert out.next_index() == 2 and path.read_text().endswith('{"pair_in')  # next_index changes nothing
    assert out.open() == 2
    out.close()
    assert [r["pair_index"] for r in _records(path)] == [0, 1] and "torn line (9 bytes" in caplog.text
    only_torn = tmp_path / "torn.jsonl"
    only_torn.write_text('{"pair_index": 0, "pa')
    assert PoseLineFile(only_torn).open() == 0 and only_torn.read_text() == ""
    other = tmp_path / "notes.txt"
    other.write_text("a line\nanother line\n")
    with pytest.raises(ValueError, match=r"output_path '.*notes.txt' holds lines that are not pose lines"):
        PoseLineFile(other).open()
    assert other.read_text() == "a line\nanother line\n"


def test_a_run_killed_at_20_random_points_leaves_whole_lines_and_the_next_numbers_on(tmp_path):
    """A child process appends lines of 64 KiB (several pages: a kill can land inside a write) and
    is killed with SIGKILL at a random moment, 20 times; after each, the next open leaves whole
    lines only, numbered 0, 1, 2, ... with no pair twice and none skipped."""
    path = tmp_path / "poses.jsonl"
    rng = np.random.default_rng(56)
    payload = "x" * 65536
    for _ in range(20):
        pid = os.fork()
        if pid == 0:  # the child: a receiver's writes, until killed
            try:
                out = PoseLineFile(path)
                index = out.open()
                for i in range(index, index + 40):
                    out.append({"pair_index": i, "payload": payload})
                time.sleep(60)
            finally:
                os._exit(0)
        time.sleep(rng.uniform(0.0, 0.03))
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        out = PoseLineFile(path)
        next_index = out.open()
        out.close()
        records = _records(path)
        assert [r["pair_index"] for r in records] == list(range(len(records))) == list(range(next_index))
    assert next_index > 0
