"""The results of finished sweep tasks kept on disk under their content key, so that a sweep stopped
half-way (a lost machine, a stopped study run) does not redo them (:class:`SweepCache`). The folder is
``HISTOSTUDY_SWEEP_CACHE`` (:data:`SWEEP_CACHE_ENV`) when a sweep's ``cache`` is left unset.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import pickle
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["SWEEP_CACHE_ENV", "SweepCache", "files_digest", "package_digest", "resolve_sweep_cache"]

#: The environment variable that names the folder of every sweep's cache when ``cache`` is unset.
SWEEP_CACHE_ENV = "HISTOSTUDY_SWEEP_CACHE"

_KEY_LIBRARIES = ("numpy", "scipy", "torch", "opencv-python-headless", "pandas", "numba")


def _package_files(root: Path):
    profiles = root / "reporting" / "profiles"
    for path in root.rglob("*"):
        if (path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc"
                and not (path.parent == profiles and path.suffix == ".toml")):
            yield path


def files_digest(paths, root: str | os.PathLike) -> str:
    """The digest of a set of files: their names and their bytes.

    Args:
        paths: the files (``Path`` objects under ``root``).
        root: the folder their names are taken relative to.

    Returns:
        SHA-256 (hex) of each file's name relative to ``root`` and the SHA-256 of its bytes, in
        name order.

    Raises:
        ValueError: a path not under ``root``.
        OSError: a file that cannot be read.
    """
    base = Path(root)
    digest = hashlib.sha256()
    for path in sorted(paths, key=lambda p: p.relative_to(base).as_posix()):
        digest.update(path.relative_to(base).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


@functools.lru_cache(maxsize=4)
def _digest(root: str, stamp: tuple) -> str:
    return files_digest(list(_package_files(Path(root))), root)


def package_digest(package: str | os.PathLike | None = None) -> str:
    """The digest of a package's code.

    Args:
        package: the package's folder; default: this ``histostudy``.

    Returns:
        SHA-256 (hex, :func:`files_digest`) of the package's files, its profiles' ``.toml`` files
        left out (a study section keys its own parameters); computed again only when a file's size
        or time changes.
    """
    root = Path(package) if package is not None else Path(__file__).resolve().parents[1]
    # hashed again when a file's size or time changes; otherwise once per process
    stamp = tuple(sorted((p.as_posix(), p.stat().st_size, p.stat().st_mtime_ns) for p in _package_files(root)))
    return _digest(str(root), stamp)


def _tensor_content(*parts):  # stands in for a tensor in a key's bytes; never called
    raise RuntimeError("a key's bytes are hashed, never unpickled")


def _key_bytes(obj: Any) -> bytes:
    """``obj`` pickled for a key: as cloudpickle pickles it, but each torch tensor by its dtype,
    shape and bytes. Torch pickles a tensor's storage under its memory address, so the learned stages
    would pickle differently in every process and a resumed sweep would find none of its tasks."""
    import cloudpickle

    torch = sys.modules.get("torch")  # a tensor exists only where torch is imported already

    class _KeyPickler(cloudpickle.CloudPickler):
        def reducer_override(self, value):
            if torch is not None and isinstance(value, torch.Tensor) and value.layout == torch.strided:
                t = value.detach().cpu().contiguous().reshape(-1)
                if not t.is_quantized:  # a quantized tensor keys as torch pickles it (a miss at worst)
                    return _tensor_content, (str(t.dtype), tuple(value.shape), value.requires_grad,
                                             t.view(torch.uint8).numpy().tobytes())
            return super().reducer_override(value)

    buffer = io.BytesIO()
    _KeyPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buffer.getvalue()


def resolve_sweep_cache(cache: str | os.PathLike | None = None) -> Path | None:
    """The cache folder of a sweep: ``cache`` itself, else :data:`SWEEP_CACHE_ENV` when it is set and
    not empty, else None (nothing kept). The one place that reads the variable."""
    if cache is not None:
        return Path(cache)
    value = os.environ.get(SWEEP_CACHE_ENV, "").strip()
    return Path(value) if value else None


class SweepCache:
    """The finished tasks of one sweep, kept in ``folder``.

    A task's result is stored under its content key: the task function's module and name, the
    task's argument and seed, the sweep's shared inputs, the package's code (:func:`package_digest`),
    the numerical libraries' versions, the instruction-set restriction in force and ``context``. A
    change in any of these misses the cache and runs the task; what is found was made by the same
    code on the same inputs. The keys hash pickled bytes, torch tensors by their content (so a
    network's weights key alike in every process); inputs that still pickle differently in another
    process only miss, never mislead. Entries are pickles written atomically (one file per
    task); a file that cannot be read is a miss.

    Args:
        folder: where the entries are kept.
        task_fn: the sweep's task function.
        shared: the sweep's shared inputs.
        context: what else the results depend on (the executor's kind and threads: torch's kernels
            may round differently with other thread pools).
    """

    def __init__(self, folder: str | os.PathLike, task_fn: Callable, shared: dict, context: tuple = ()):
        from .machine import isa_restriction
        from .provenance import package_versions

        self.folder = Path(folder)
        name = f"{getattr(task_fn, '__module__', '')}.{getattr(task_fn, '__qualname__', repr(task_fn))}"
        base = hashlib.sha256()
        for part in (name, package_digest(), repr(sorted(package_versions(_KEY_LIBRARIES).items())),
                     repr(sorted(isa_restriction().items())), repr(context)):
            base.update(part.encode() + b"\0")
        base.update(hashlib.sha256(_key_bytes(shared)).digest())
        self._base = base.digest()
        self.hits = 0

    def key(self, call: tuple) -> str:
        """The key of one task's call (its argument, and its seed when the sweep has one)."""
        return hashlib.sha256(self._base + _key_bytes(call)).hexdigest()

    def _path(self, key: str) -> Path:
        return self.folder / key[:2] / f"{key}.pkl"

    def load(self, key: str) -> tuple[bool, Any]:
        """``(True, result)`` where the task's result is stored and readable, else ``(False, None)``."""
        try:
            with open(self._path(key), "rb") as fh:
                value = pickle.load(fh)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
            return False, None
        self.hits += 1
        return True, value

    def store(self, key: str, value: Any) -> None:
        """Keep ``value`` as the task's result (atomically: a stopped write leaves no entry)."""
        from .io import atomic_path

        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
