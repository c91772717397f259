"""Stopping a batch run cleanly on SIGINT or SIGTERM: the signal raised as :class:`StudyInterrupted`,
no notebook kernel left running, no temporary file left half-written (docs/report.md, "Stopping a
run")."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from pathlib import Path

__all__ = ["StudyInterrupted", "remove_temporaries", "signals_interrupt", "stop_kernels"]


class StudyInterrupted(Exception):
    """The batch run was stopped by a signal (raised inside :func:`signals_interrupt`).

    Args:
        signal_name: the signal's name, ``"SIGTERM"`` or ``"SIGINT"`` (kept as ``signal_name``).
    """

    def __init__(self, signal_name: str):
        super().__init__(f"interrupted by {signal_name}")
        self.signal_name = signal_name


@contextlib.contextmanager
def signals_interrupt():
    """Within the block, SIGTERM and SIGINT raise :class:`StudyInterrupted` (main thread only;
    elsewhere, as in a notebook kernel's worker thread, signals keep their handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_interrupted(signum, frame):
        raise StudyInterrupted(signal.Signals(signum).name)

    previous = {sig: signal.signal(sig, raise_interrupted) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux ``/proc``; elsewhere none are found)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def stop_kernels(grace_s: float = 5.0) -> list[int]:
    """Terminate this process's notebook kernels (children running ``ipykernel``), then kill the
    ones still alive after ``grace_s``; returns their pids."""
    kernels = []
    for pid in _children(os.getpid()):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
        except OSError:
            continue
        if b"ipykernel" in cmdline:
            kernels.append(pid)
    for pid in kernels:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    end = time.monotonic() + grace_s
    for pid in kernels:
        while time.monotonic() < end:
            with contextlib.suppress(ChildProcessError):
                if os.waitpid(pid, os.WNOHANG)[0] == pid:
                    break
            if not Path(f"/proc/{pid}").exists():
                break
            time.sleep(0.05)
        else:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
    return kernels


def remove_temporaries(*folders: Path) -> list[Path]:
    """Remove the temporary files of :func:`histostudy.core.atomic_path` (``.<stem>.*.tmp*``) that a
    killed writer left in ``folders`` (recursively); returns what was removed."""
    removed = []
    for folder in folders:
        if not Path(folder).is_dir():
            continue
        for path in Path(folder).rglob(".*.tmp*"):
            if path.is_file():
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed
