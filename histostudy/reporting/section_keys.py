"""A section's content key (:func:`section_key`): the digest of what its numbers depend on (the
notebook, its parameters, the package's code, the shipped weights, the libraries' versions), so that
a rerun keeps a finished section (:func:`kept_section`), and the estimate of its wall time
(docs/report.md, "Reruns, resumed runs and the time left")."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from histostudy.core import atomic_write_json, files_digest, package_digest, shipped_dir
from histostudy.core.provenance import git_commit, package_versions

__all__ = ["ATTEMPTS_FILE", "KEY_FILE", "SectionKey", "changed_parts", "code_digest", "earlier_attempts",
           "estimate_seconds", "kept_section", "record_attempt", "record_key", "remove_key", "section_key",
           "stored_key", "weights_digest"]

#: The file in a section folder that holds its content key and the run that made it.
KEY_FILE = "section_key.json"

#: The file in a section folder that holds the section's stopped attempts under its current key
#: (interrupted or failed); folded into :data:`KEY_FILE` when the section finishes.
ATTEMPTS_FILE = "section_attempts.json"

#: The libraries whose version enters the key: they compute the numbers.
_KEY_LIBRARIES = ("python", "numpy", "scipy", "torch", "opencv-python-headless", "pandas", "numba")

#: Parameters that say where a section goes, not what it computes.
_PLACE_PARAMETERS = ("output_dir",)


@dataclass(frozen=True)
class SectionKey:
    """A section's content key: ``parts`` (notebook, parameters, code, weights, libraries: one
    SHA-256 each) and ``key``, the SHA-256 of them all."""
    key: str
    parts: dict


def code_digest(package: str | os.PathLike | None = None) -> str:
    """SHA-256 of the package's files (names and bytes), its profiles' ``.toml`` files left out
    (:func:`histostudy.core.package_digest`, which the sweeps' task cache keys too)."""
    return package_digest(package)


def weights_digest(models_dir: str | os.PathLike | None = None) -> str:
    """SHA-256 of the shipped networks' files (``data/models``); of nothing where there are none."""
    folder = Path(models_dir) if models_dir is not None else shipped_dir("models")
    files = [p for p in folder.rglob("*") if p.is_file()] if folder.is_dir() else []
    return files_digest(files, folder)


def _sha256_json(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


def section_key(notebook: str | os.PathLike, parameters: dict, *, package: str | os.PathLike | None = None,
                models_dir: str | os.PathLike | None = None) -> SectionKey:
    """The content key of running ``notebook`` with ``parameters`` (the profile's table for it, seed
    and profile name included; where the section is written does not count)."""
    nb_path = Path(notebook)
    if not nb_path.is_file():
        raise ValueError(f"notebook {str(nb_path)!r} is not a file (expected a study notebook NN_name.ipynb)")
    if not isinstance(parameters, dict):
        raise TypeError(f"parameters must be a dict (the notebook's parameters), got {type(parameters).__name__}")
    versions = package_versions(tuple(name for name in _KEY_LIBRARIES if name != "python"))
    parts = {
        "notebook": hashlib.sha256(nb_path.read_bytes()).hexdigest(),
        "parameters": _sha256_json({k: v for k, v in parameters.items() if k not in _PLACE_PARAMETERS}),
        "code": code_digest(package),
        "weights": weights_digest(models_dir),
        "libraries": _sha256_json({k: versions[k] for k in _KEY_LIBRARIES if k in versions}),
    }
    return SectionKey(_sha256_json(parts), parts)


def stored_key(section_dir: str | os.PathLike) -> dict | None:
    """The record of ``section_dir/section_key.json``, or None where there is none or it is unreadable."""
    return _keyed_record(Path(section_dir) / KEY_FILE)


def _keyed_record(path: Path) -> dict | None:
    """The JSON object of ``path`` that names its content key (a string ``"key"``), or None where
    there is none or it is unreadable."""
    try:
        with open(path, encoding="utf-8") as fh:
            record = json.load(fh)
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("key"), str) else None


def kept_section(section_dir: str | os.PathLike, executed_notebook: str | os.PathLike, key: SectionKey) -> dict | None:
    """The stored record when ``section_dir`` holds a finished section of this ``key`` (its results
    and the executed notebook still there), else None: the section must run."""
    record = stored_key(section_dir)
    if record is None or record["key"] != key.key:
        return None
    if not (Path(section_dir) / "results.json").is_file() or not Path(executed_notebook).is_file():
        return None
    return record


def changed_parts(section_dir: str | os.PathLike, key: SectionKey) -> list[str]:
    """Which parts of ``key`` differ from the section's stored key (all of them where none is stored)."""
    record = stored_key(section_dir)
    stored = record.get("parts", {}) if record else {}
    return [name for name, digest in key.parts.items() if stored.get(name) != digest]


def remove_key(section_dir: str | os.PathLike) -> None:
    """Forget the section's key before it runs again: a run stopped half-way leaves none."""
    try:
        os.remove(Path(section_dir) / KEY_FILE)
    except FileNotFoundError:
        pass


def record_key(section_dir: str | os.PathLike, key: SectionKey, *, notebook: str, profile: str, parameters: dict,
               seconds: float, cpu_seconds: float | None, machine: dict, attempts: dict | None = None) -> Path:
    """Write the finished section's key with what made it: the notebook, profile and parameters, its
    wall time and CPU time (s; None where other notebooks ran beside it), the machine and commit, and
    ``attempts`` (:func:`earlier_attempts`: the stopped attempts before it, whose
    :data:`ATTEMPTS_FILE` it then removes; None: none)."""
    path = atomic_write_json(Path(section_dir) / KEY_FILE, {
        "key": key.key, "parts": key.parts, "notebook": notebook, "profile": profile,
        "parameters": {k: v for k, v in parameters.items() if k not in _PLACE_PARAMETERS},
        "seconds": float(seconds), "cpu_seconds": None if cpu_seconds is None else float(cpu_seconds),
        "earlier_attempts": attempts,
        "finished_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "git_commit": git_commit(), "machine": machine,
    })
    (Path(section_dir) / ATTEMPTS_FILE).unlink(missing_ok=True)
    return path


def record_attempt(section_dir: str | os.PathLike, key: SectionKey, *, status: str, seconds: float | None,
                   cpu_seconds: float | None) -> Path:
    """Add a stopped attempt of the section (``status`` "interrupted" or "failed", its wall and CPU
    time in s, None where not known) to its :data:`ATTEMPTS_FILE`. Attempts under another key are
    dropped: they computed something else, and their sweep tasks are not this key's."""
    path = Path(section_dir) / ATTEMPTS_FILE
    stored = _stored_attempts(path)
    attempts = stored["attempts"] if stored is not None and stored["key"] == key.key else []
    attempts.append({"status": status, "seconds": None if seconds is None else float(seconds),
                     "cpu_seconds": None if cpu_seconds is None else float(cpu_seconds),
                     "ended_utc": datetime.now(UTC).isoformat(timespec="seconds")})
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_json(path, {"key": key.key, "attempts": attempts})


def earlier_attempts(section_dir: str | os.PathLike, key: SectionKey) -> dict | None:
    """The section's stopped attempts under ``key`` (:func:`record_attempt`): ``{"count", "seconds",
    "cpu_seconds"}``, the times summed (CPU None where an attempt's is not known), or None where there
    were none. A resumed section's own time counts only its last attempt; these are the rest."""
    stored = _stored_attempts(Path(section_dir) / ATTEMPTS_FILE)
    if stored is None or stored["key"] != key.key or not stored["attempts"]:
        return None
    attempts = stored["attempts"]
    cpu = [a.get("cpu_seconds") for a in attempts]
    return {"count": len(attempts), "seconds": float(sum(a.get("seconds") or 0.0 for a in attempts)),
            "cpu_seconds": None if any(c is None for c in cpu) else float(sum(cpu))}


def _stored_attempts(path: Path) -> dict | None:
    stored = _keyed_record(path)
    return stored if stored is not None and isinstance(stored.get("attempts"), list) else None


def estimate_seconds(notebook: str, parameters: dict, places) -> tuple[float, str] | None:
    """The wall time (s) of ``notebook`` with ``parameters`` in the last finished run found in
    ``places`` (output folders, a published run's folder first or last as the caller prefers), and
    where it was measured (date and machine); None where no run had these parameters."""
    wanted = {k: v for k, v in parameters.items() if k not in _PLACE_PARAMETERS}
    for place in places:
        record = stored_key(Path(place) / notebook)
        if record and _same_parameters(record.get("parameters"), wanted):
            machine = record.get("machine") or {}
            where = (f"the run of {str(record.get('finished_utc', ''))[:10]} on {machine.get('cpu_model', 'a CPU')}, "
                     f"{machine.get('cpus', '?')} cores")
            return float(record["seconds"]), where
    return None


def _same_parameters(a, b) -> bool:
    return _sha256_json(a) == _sha256_json(b)
