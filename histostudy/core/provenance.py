"""Where a result came from: package versions, git commit, machine. Recorded in every results JSON."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from .machine import cpu_model, isa_flags, isa_restriction

__all__ = ["git_commit", "package_versions", "provenance"]

_PACKAGES = ("histostudy", "numpy", "scipy", "torch", "opencv-python-headless", "pyvista", "vtk",
             "statsmodels", "ur-rtde", "papermill", "pandas", "matplotlib")

REPO_ROOT = Path(__file__).resolve().parents[2]


def package_versions(packages=_PACKAGES) -> dict[str, str]:
    """Installed version of each distribution, or ``"not installed"``."""
    out = {"python": platform.python_version()}
    for name in packages:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def git_commit(repo: str | os.PathLike = REPO_ROOT) -> str:
    """The commit a result came from.

    Args:
        repo: the repository's folder (default: this package's checkout).

    Returns:
        HEAD's commit hash, with ``-dirty`` if tracked files differ from it; ``"unknown"`` outside
        git or without the ``git`` command.
    """
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repo,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{commit}-dirty" if dirty else commit


def provenance() -> dict:
    """Everything needed to tell two runs apart, recorded beside every result.

    Returns:
        A JSON-ready dict: ``created_utc`` (ISO time), ``git_commit`` (:func:`git_commit`),
        ``versions`` (the Python and key packages' versions) and ``machine`` (platform, CPU count,
        interpreter, CPU model, instruction-set flags and any restriction to AVX2).
    """
    return {
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "git_commit": git_commit(),
        "versions": package_versions(),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "executable": sys.executable,
                    "cpu_model": cpu_model(), "isa_flags": isa_flags(), "isa_restriction": isa_restriction()},
    }
