"""The treatment journal (§II-D): an SQLite record of every focal point (an intent before its first pulse,
a done after its last), one process at a time, checked on opening (docs/robot.md)."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import socket
import sqlite3
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path, to_jsonable

from .plan import TreatmentPlan

__all__ = ["JOURNAL_FORMAT", "JOURNAL_VERSION", "JournalError", "JournalLockedError", "TreatmentJournal"]

JOURNAL_FORMAT = "histostudy.treatment_journal"
#: 1: a JSON file rewritten after each point (migrated on open); 2: SQLite with intent and done.
JOURNAL_VERSION = 2
_SQLITE_MAGIC = b"SQLite format 3\x00"
_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE points (
    idx INTEGER PRIMARY KEY CHECK (idx >= 0),
    point_carm_mm TEXT NOT NULL,
    commanded_T_base_tcp TEXT NOT NULL,
    reached_T_base_tcp TEXT NOT NULL,
    intent_utc TEXT NOT NULL,
    done_utc TEXT,
    pulses INTEGER,
    resolution TEXT CHECK (resolution IN ('refired', 'skipped'))
);
"""
CALIBRATION_KEYS = ("T_base_carm", "R_base_tcp", "T_flange_tcp")


class JournalError(ValueError):
    """A journal that cannot be trusted: not a journal, another plan or calibration, or records
    that contradict each other (edited, truncated, from a newer version)."""


class JournalLockedError(RuntimeError):
    """Another process holds the journal; a second run would fire its points again."""


def _plan_fingerprint(plan_dict: dict) -> str:
    """:meth:`TreatmentPlan.fingerprint` of a plan's JSON (floats survive JSON exactly)."""
    return hashlib.sha256(json.dumps(plan_dict, sort_keys=True).encode("utf-8")).hexdigest()


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="microseconds")


def _dumps(value) -> str:
    return json.dumps(to_jsonable(value), separators=(",", ":"))


class TreatmentJournal:
    """An open journal, held exclusively by this process until :meth:`close` (a context manager).

    Open it with :meth:`open_for_run` (create, migrate or resume, checked against the plan and the
    calibration) or :meth:`open_for_reading` (any valid journal, no lock). ``finished`` holds the
    finished points' indices (a prefix of the plan), ``uncertain`` the index of the point with an
    intent and no done, or None.
    """

    def __init__(self, path: Path, connection: sqlite3.Connection, lock_fd: int | None):
        self.path, self._db, self._lock_fd = path, connection, lock_fd
        self.meta = {k: v for k, v in connection.execute("SELECT key, value FROM meta")}
        self.n_planned = int(self.meta["n_planned"])
        self.finished, self.uncertain = self._check()

    # -- opening -------------------------------------------------------------------------------

    @classmethod
    def open_for_run(cls, path: str | os.PathLike, plan: TreatmentPlan, calibration: dict) -> TreatmentJournal:
        """Lock ``path``, then create it for ``plan`` or resume it; ``calibration`` maps
        :data:`CALIBRATION_KEYS` to arrays (``T_flange_tcp`` may be None). Raises
        :class:`JournalLockedError` if another process holds it, :class:`JournalError` if it
        belongs to another plan or calibration or fails its checks. Nothing is written to a
        journal that is refused."""
        path = Path(path)
        lock_fd = _lock(path)
        try:
            if not path.exists():
                _create(path, plan.to_dict(), plan.fingerprint(), calibration, points=[])
            elif not _is_sqlite(path):
                _migrate_v1(path)
            journal = cls(path, _connect(path), lock_fd)
        except BaseException:
            os.close(lock_fd)
            raise
        try:
            journal._check_matches(plan, calibration)
        except BaseException:
            journal.close()
            raise
        return journal

    @classmethod
    def open_for_reading(cls, path: str | os.PathLike) -> TreatmentJournal:
        """A checked view of the journal at ``path`` (SQLite or version-1 JSON), without the lock."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"journal {path} does not exist")
        if not _is_sqlite(path):
            points, head = _read_v1(path)
            db = sqlite3.connect(":memory:")
            _initialise(db, head["plan"], head["plan_fingerprint"], head, points)
            return cls(path, db, None)
        return cls(path, _connect(path, read_only=True), None)

    def _check(self) -> tuple[list[int], int | None]:
        meta = self.meta
        if meta.get("format") != JOURNAL_FORMAT:
            raise JournalError(f"journal {self.path} is not a treatment journal (format {meta.get('format')!r})")
        if meta.get("version") != str(JOURNAL_VERSION):
            raise JournalError(f"journal {self.path} has version {meta.get('version')!r}; "
                               f"this code reads {JOURNAL_VERSION}")
        plan = json.loads(meta["plan"])
        if _plan_fingerprint(plan) != meta["plan_fingerprint"] or len(plan["points_mm"]) != self.n_planned:
            raise JournalError(f"journal {self.path}: its plan does not match its recorded fingerprint (edited?)")
        rows = self._db.execute("SELECT idx, done_utc IS NOT NULL FROM points ORDER BY idx").fetchall()
        finished = [i for i, done in rows if done]
        open_ = [i for i, done in rows if not done]
        if finished != list(range(len(finished))):
            raise JournalError(f"journal {self.path}: the finished points {finished[:8]}... are not the plan's "
                               "first points in order (records missing or added)")
        if len(open_) > 1 or (open_ and open_[0] != len(finished)):
            raise JournalError(f"journal {self.path}: intents without a done at {open_[:8]}: only the point after "
                               "the last finished one can be uncertain")
        if rows and rows[-1][0] >= self.n_planned:
            raise JournalError(f"journal {self.path} holds point {rows[-1][0]} of a {self.n_planned}-point plan")
        if int(meta["n_finished"]) != len(finished):
            raise JournalError(f"journal {self.path} counts {meta['n_finished']} finished points but holds "
                               f"{len(finished)} (edited or truncated)")
        return finished, (open_[0] if open_ else None)

    def _check_matches(self, plan: TreatmentPlan, calibration: dict) -> None:
        if self.meta["plan_fingerprint"] != plan.fingerprint():
            raise JournalError(f"journal {self.path} belongs to another plan (fingerprint differs); "
                               "refusing to resume it with this plan")
        for key in CALIBRATION_KEYS:
            a, b = json.loads(self.meta[key]), to_jsonable(calibration[key])
            if (a is None) != (b is None) or (a is not None and not np.allclose(a, b, rtol=0, atol=1e-9)):
                raise JournalError(f"journal {self.path} was written with another {key} ({a!r}); got {b!r}: "
                                   "refusing to resume")

    # -- records -------------------------------------------------------------------------------

    @property
    def completed(self) -> bool:
        return len(self.finished) == self.n_planned

    def record_intent(self, index: int, point_carm_mm, commanded, reached) -> None:
        """Commit, before the first pulse at ``index``, that the arm stands there to fire."""
        with self._transaction() as db:
            db.execute("INSERT INTO points (idx, point_carm_mm, commanded_T_base_tcp, reached_T_base_tcp, intent_utc)"
                       " VALUES (?, ?, ?, ?, ?) ON CONFLICT (idx) DO UPDATE SET reached_T_base_tcp = excluded."
                       "reached_T_base_tcp, intent_utc = excluded.intent_utc",
                       (index, _dumps(point_carm_mm), _dumps(commanded), _dumps(reached), _now()))
        self.uncertain = index

    def record_done(self, index: int, pulses: int, resolution: str | None = None) -> None:
        """Commit that ``index`` is finished: ``pulses`` fired (0 when skipped), and how an uncertain
        point was settled (``"refired"``, ``"skipped"``) if it was one."""
        if index != self.uncertain:
            raise RuntimeError(f"point {index} has no open intent (the open one is {self.uncertain})")
        with self._transaction() as db:
            db.execute("UPDATE points SET done_utc = ?, pulses = ?, resolution = ? WHERE idx = ?",
                       (_now(), int(pulses), resolution, index))
            db.execute("UPDATE meta SET value = ? WHERE key = 'n_finished'", (str(len(self.finished) + 1),))
        self.finished.append(index)
        self.uncertain = None

    def rows(self) -> list[tuple]:
        """``(idx, point, commanded, reached, pulses, resolution)`` of the finished points, in order."""
        out = []
        for idx, p, c, r, pulses, res in self._db.execute(
                "SELECT idx, point_carm_mm, commanded_T_base_tcp, reached_T_base_tcp, pulses, resolution FROM points"
                " WHERE done_utc IS NOT NULL ORDER BY idx"):
            out.append((idx, json.loads(p), json.loads(c), json.loads(r), pulses, res))
        return out

    @contextlib.contextmanager
    def _transaction(self):
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield self._db
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")

    def close(self) -> None:
        self._db.close()
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the flock
            self._lock_fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _lock(path: Path) -> int:
    path.parent.mkdir(parents=True, exist_ok=True)
    lock_path = path.with_name(path.name + ".lock")
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 512, 0).decode("utf-8", "replace").strip() or "another process"
        os.close(fd)
        raise JournalLockedError(f"journal {path} is in use by {holder}; a second run on it would fire its points "
                                 "twice: wait for that run to end (its lock goes when it exits)") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {_now()}".encode(), 0)
    return fd


def _is_sqlite(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(len(_SQLITE_MAGIC)) == _SQLITE_MAGIC


def _connect(path: Path, read_only: bool = False) -> sqlite3.Connection:
    uri = f"file:{path}?mode=ro" if read_only else f"file:{path}?mode=rw"
    try:
        db = sqlite3.connect(uri, uri=True, isolation_level=None)
        if not read_only:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")
        db.execute("SELECT 1 FROM meta LIMIT 1")
    except sqlite3.DatabaseError as exc:
        raise JournalError(f"journal {path} is not a readable treatment journal ({exc})") from None
    return db


def _initialise(db: sqlite3.Connection, plan_dict: dict, fingerprint: str, calibration: dict, points: list) -> None:
    db.executescript(_SCHEMA)
    meta = {"format": JOURNAL_FORMAT, "version": str(JOURNAL_VERSION), "plan": _dumps(plan_dict),
            "plan_fingerprint": fingerprint, "n_planned": str(len(plan_dict["points_mm"])),
            "n_finished": str(len(points)), "created_utc": _now()}
    meta.update({k: _dumps(calibration.get(k)) for k in CALIBRATION_KEYS})
    db.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
    now = _now()
    db.executemany("INSERT INTO points VALUES (?, ?, ?, ?, ?, ?, ?, NULL)",
                   [(p["index"], _dumps(p["point_carm_mm"]), _dumps(p["commanded_T_base_tcp"]),
                     _dumps(p["reached_T_base_tcp"]), now, now, int(p["pulses"])) for p in points])
    db.commit()


def _create(path: Path, plan_dict: dict, fingerprint: str, calibration: dict, points: list) -> None:
    """Write a new journal whole: built under a temporary name, then renamed into place."""
    with atomic_path(path, suffix=".sqlite") as tmp:
        tmp.unlink()  # sqlite makes its own file
        db = sqlite3.connect(tmp)
        try:
            _initialise(db, plan_dict, fingerprint, calibration, points)
        finally:
            db.close()


def _read_v1(path: Path) -> tuple[list, dict]:
    """The points and header of a version-1 (JSON) journal, checked as strictly as version 2."""
    try:
        journal = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise JournalError(f"journal {path} is neither SQLite nor valid JSON ({exc})") from None
    if not isinstance(journal, dict) or journal.get("format") != JOURNAL_FORMAT or journal.get("version") != 1:
        raise JournalError(f"journal {path} is not a treatment journal (format {JOURNAL_FORMAT!r}, version 1 or 2)")
    missing = [k for k in ("plan", "plan_fingerprint", "points", "completed", *CALIBRATION_KEYS) if k not in journal]
    if missing:
        raise JournalError(f"journal {path} lacks {missing}")
    points = journal["points"]
    need = ("index", "point_carm_mm", "commanded_T_base_tcp", "reached_T_base_tcp", "pulses")
    if not isinstance(points, list) or any(not isinstance(p, dict) or any(k not in p for k in need) for p in points):
        raise JournalError(f"journal {path}: every point must hold {need}")
    n_planned = len(journal["plan"].get("points_mm", []))
    if [p["index"] for p in points] != list(range(len(points))) or len(points) > n_planned:
        raise JournalError(f"journal {path} holds points {[p['index'] for p in points][:8]}..., not the first "
                           f"points of its {n_planned}-point plan in order")
    if bool(journal["completed"]) != (len(points) == n_planned):
        raise JournalError(f"journal {path} says completed={journal['completed']} with {len(points)} of "
                           f"{n_planned} points (edited?)")
    return points, journal


def _migrate_v1(path: Path) -> None:
    """Replace a version-1 JSON journal by its SQLite form; the JSON is kept as ``<name>.v1.json``."""
    points, head = _read_v1(path)
    if _plan_fingerprint(head["plan"]) != head["plan_fingerprint"]:
        raise JournalError(f"journal {path}: its plan does not match its recorded fingerprint (edited?)")
    backup = path.with_name(path.name + ".v1.json")
    backup.write_bytes(path.read_bytes())
    _create(path, head["plan"], head["plan_fingerprint"], head, points)
