"""What every ``histostudy`` command shares with the terminal, in the habits of dcmtk and git: results
on stdout (one JSON line, :func:`emit`), talk on stderr through the ``histostudy.cli`` logger (``-q``
errors only, ``-v``/``-vv`` more), a progress bar on a terminal (:class:`Steps`), and errors as
``histostudy <command>: <message>`` with exit status 2 for bad input, 1 for a refusal (:func:`fail`)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time

__all__ = ["Steps", "add_command", "common_parent", "configure_logging", "elapsed_since", "emit", "fail", "log",
           "positive_int"]

#: The commands' own lines (stderr).
log = logging.getLogger("histostudy.cli")

_HANDLER_NAME = "histostudy-cli-stderr"


def common_parent(version: str) -> argparse.ArgumentParser:
    """The options of every subcommand: ``--version``, ``-q/--quiet`` and ``-v/--verbose``.

    Args:
        version: the package's version, printed by ``--version``.

    Returns:
        A parent parser (no ``--help``) to pass in ``parents=``.
    """
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument("--version", action="version", version=f"histostudy {version}")
    talk = parent.add_mutually_exclusive_group()
    talk.add_argument("-q", "--quiet", action="store_true",
                      help="errors only on stderr: no progress, no lines of the command's own")
    talk.add_argument("-v", "--verbose", action="count", default=0,
                      help="more on stderr: -v the library's steps (INFO), -vv everything (DEBUG)")
    return parent


def add_command(sub, name: str, parents, *, help: str, description: str, example: str):
    """Add a subcommand whose ``--help`` shows its ``description`` and an ``example``.

    Args:
        sub: the subparsers of the ``histostudy`` parser.
        name: the subcommand's name.
        parents: parent parsers (:func:`common_parent`).
        help: its line in ``histostudy --help``.
        description: its paragraph in ``histostudy <name> --help``.
        example: shell lines, shown indented under "example:".

    Returns:
        The subcommand's parser.
    """
    return sub.add_parser(name, parents=parents, help=help, description=description,
                          epilog="example:\n" + "\n".join("  " + line for line in example.strip().splitlines()),
                          formatter_class=argparse.RawDescriptionHelpFormatter)


def configure_logging(args) -> None:
    """Route the ``histostudy`` loggers to stderr at the levels ``-q``/``-v`` ask for, and set
    ``args.progress`` (a bar only on a terminal, not with ``-q``). Idempotent: ``main`` may run many
    times in one process.

    Args:
        args: the parsed arguments (``quiet``, ``verbose``; missing ones read as unset).
    """
    quiet, verbose = bool(getattr(args, "quiet", False)), int(getattr(args, "verbose", 0) or 0)
    own = logging.ERROR if quiet else (logging.DEBUG if verbose else logging.INFO)
    library = logging.ERROR if quiet else {0: logging.WARNING, 1: logging.INFO}.get(verbose, logging.DEBUG)
    root = logging.getLogger("histostudy")
    for handler in list(root.handlers):
        if handler.get_name() == _HANDLER_NAME:
            root.removeHandler(handler)
    handler = _StderrHandler()
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root.addHandler(handler)
    root.setLevel(library)
    log.setLevel(own)
    args.progress = not quiet and sys.stderr.isatty()


class _StderrHandler(logging.StreamHandler):
    """A handler on whatever ``sys.stderr`` is at each record (pytest and notebooks swap it)."""

    def __init__(self):
        super().__init__(sys.stderr)

    def emit(self, record):
        self.stream = sys.stderr
        super().emit(record)


def positive_int(value: str) -> int:
    """An argparse ``type`` for an integer argument >= 1.

    Args:
        value: the argument's text.

    Returns:
        The integer.

    Raises:
        argparse.ArgumentTypeError: ``value`` is not an integer >= 1.
    """
    try:
        number = int(value)
    except ValueError:
        number = 0
    if number < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value!r}")
    return number


def emit(summary: dict) -> None:
    """Print the command's summary as one line of JSON on stdout.

    Args:
        summary: JSON-able after :func:`histostudy.core.to_jsonable` (numpy arrays, paths; NaN and
            infinity become null).
    """
    from histostudy.core import to_jsonable

    print(json.dumps(to_jsonable(summary), allow_nan=False), flush=True)


def fail(command: str, exc: BaseException | str, code: int = 2) -> int:
    """Report a bad input or a refusal on stderr as ``histostudy <command>: <message>``, and as the
    command's summary line on stdout (:func:`emit`: ``command``, ``exit_code``, ``refused`` (code
    1) or ``bad_input`` (code 2), ``error``), so that a script reading stdout sees every outcome.

    Args:
        command: the subcommand's name.
        exc: the error or message.
        code: the exit status: 2 bad input, 1 refusal.

    Returns:
        ``code``.
    """
    print(f"histostudy {command}: {exc}", file=sys.stderr, flush=True)
    emit({"command": command, "exit_code": code, "refused": code == 1, "bad_input": code == 2, "error": str(exc)})
    return code


class Steps:
    """A progress bar over named steps (tqdm, on stderr) that redraws every half second, so that a long
    step shows its elapsed time. Use as a context manager and call :meth:`step` before each step.

    Args:
        total: the number of steps.
        enabled: draw the bar (``args.progress``); otherwise every call does nothing.
        label: the bar's label.
    """

    def __init__(self, total: int, *, enabled: bool, label: str):
        self.total = int(total)
        self.enabled, self.label = bool(enabled), label
        self._bar, self._stop, self._thread, self._started = None, threading.Event(), None, False

    def __enter__(self):
        if self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=self.label, file=sys.stderr, leave=False,
                             bar_format="{desc}: {n_fmt}/{total_fmt} [{elapsed}] {postfix}")
            self._thread = threading.Thread(target=self._tick, daemon=True, name="histostudy-progress")
            self._thread.start()
        return self

    def step(self, name: str) -> None:
        """Mark the previous step done and show ``name`` as the one running.

        Args:
            name: the step's name.
        """
        if self._bar is None:
            return
        if self._started:
            self._bar.update(1)
        self._started = True
        self._bar.set_postfix_str(name, refresh=True)

    def _tick(self) -> None:
        while not self._stop.wait(0.5):
            if self._bar is not None:
                self._bar.refresh()

    def close(self) -> None:
        """Remove the bar (idempotent: also at the end of the ``with`` block)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __exit__(self, *exc_info):
        self.close()
        return False


def elapsed_since(t0: float) -> float:
    """Seconds since ``t0``, for summaries' ``wall_s``.

    Args:
        t0: a :func:`time.monotonic` reading (s).

    Returns:
        The elapsed seconds, rounded to ms.
    """
    return round(time.monotonic() - t0, 3)
