"""Foundations every layer uses, no paper section of their own: file writes that are atomic and
honour the umask (``io``), the one seeding policy (``seeding``: every random draw takes a seed or a
``numpy.random.Generator``), and the provenance recorded beside every result and checkpoint
(``provenance``). See docs/architecture.md, "Seeding and determinism".
"""

from .io import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text, to_jsonable
from .provenance import git_commit, package_versions, provenance
from .seeding import as_generator

__all__ = [
    "as_generator",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "git_commit",
    "package_versions",
    "provenance",
    "to_jsonable",
]
