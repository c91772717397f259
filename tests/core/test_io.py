"""Atomic writes: the file appears whole or not at all."""

import json

import numpy as np
import pytest

from histostudy.core import atomic_path, atomic_write_json, atomic_write_text, to_jsonable


def test_atomic_write_replaces_whole_file(tmp_path):
    path = tmp_path / "sub" / "a.txt"
    atomic_write_text(path, "first")
    atomic_write_text(path, "second")
    assert path.read_text() == "second"
    assert [p.name for p in path.parent.iterdir()] == ["a.txt"]


def test_failed_writer_leaves_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "report.md"
    atomic_write_text(path, "complete")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash mid-write")
    assert path.read_text() == "complete"
    assert [p.name for p in tmp_path.iterdir()] == ["report.md"]


def test_temporary_keeps_suffix_for_format_sniffing_writers(tmp_path):
    with atomic_path(tmp_path / "fig.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path
        tmp.write_bytes(b"x")


def test_json_conversion_of_numpy_and_nan(tmp_path):
    obj = {"a": np.float32(1.5), "b": np.arange(3), "c": float("nan"), "d": (np.int64(2), np.bool_(True))}
    assert to_jsonable(obj) == {"a": 1.5, "b": [0, 1, 2], "c": None, "d": [2, True]}
    path = atomic_write_json(tmp_path / "r.json", obj)
    assert json.loads(path.read_text())["c"] is None


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_written_files_honour_the_umask_like_a_plain_open(tmp_path, umask, mode):
    import os
    import stat

    from histostudy.core.io import process_umask

    old = os.umask(umask)
    try:
        assert process_umask() == umask
        written = atomic_write_text(tmp_path / f"r{umask:o}.md", "report")
        with open(tmp_path / f"plain{umask:o}.md", "w") as fh:  # the reference: what open() gives
            fh.write("x")
        assert stat.S_IMODE(written.stat().st_mode) == mode
        assert stat.S_IMODE((tmp_path / f"plain{umask:o}.md").stat().st_mode) == mode
    finally:
        os.umask(old)
