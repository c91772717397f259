"""Atomic file output: every file the study writes appears whole or not at all. A writer writes a
temporary file beside the destination (same file system), renamed into place by ``os.replace`` only
when it finished without an exception; a crash leaves at most a ``.tmp`` file no reader opens.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_json", "atomic_write_text", "process_umask",
           "to_jsonable"]


def process_umask() -> int:
    """The process's file-mode creation mask (e.g. 0o022), read without changing it where the OS
    says it (Linux ``/proc/self/status``); elsewhere set and restored at once."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """A temporary path beside ``path`` (a context manager), renamed onto ``path`` if the block succeeds.

    The file gets the mode a plain ``open(path, "w")`` would give (0o666 less the umask: 0644 under
    umask 022), not the private 0600 of the temporary file, so others can read reports and results.

    Args:
        path: the destination file; its folder is created if missing.
        suffix: the extension kept on the temporary name, for writers that pick a format from it
            (matplotlib, safetensors); default: that of ``path``.

    Returns:
        A context manager yielding the temporary ``Path`` to write; on leaving the block without an
        exception the file is synced and renamed onto ``path``, and removed otherwise.

    Raises:
        OSError: the folder cannot be created or the file not written or renamed (and whatever the
            block raises, after the temporary file is removed).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~process_umask())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically (:func:`atomic_path`).

    Args:
        path: the destination file.
        text: the text.

    Returns:
        ``path``, as a ``Path``.

    Raises:
        OSError: the file cannot be written.
    """
    return atomic_write_bytes(path, text.encode("utf-8"))


def to_jsonable(obj):
    """``obj`` with its numpy scalars and arrays, paths and tuples, at any depth, as plain JSON types.

    Args:
        obj: a dict, list, tuple, numpy array or scalar, path or plain value (dict keys become str).

    Returns:
        The converted object; non-finite floats become None (JSON has no NaN), so a missing
        measurement reads as null. Other objects are returned as they are.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if np.isfinite(value) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def atomic_write_json(path: str | os.PathLike, obj) -> Path:
    """Write ``obj`` as indented JSON, atomically (:func:`atomic_path`).

    Args:
        path: the destination file.
        obj: what to write, converted by :func:`to_jsonable`.

    Returns:
        ``path``, as a ``Path``.

    Raises:
        TypeError: ``obj`` holds something JSON cannot represent.
        OSError: the file cannot be written.
    """
    return atomic_write_text(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=False) + "\n")
