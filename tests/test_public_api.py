"""The curated public API reads as reference (docs/architecture.md, "Public API"): every function and
class a package lists in ``__all__`` documents its arguments (``Args:``), and the version lives in one
place."""

from __future__ import annotations

import importlib
import inspect
import re
import tomllib
from pathlib import Path

import pytest

import histostudy

PACKAGE = Path(histostudy.__file__).parent
REPO = PACKAGE.parent
PACKAGES = sorted(".".join(p.parent.relative_to(REPO).parts) for p in PACKAGE.rglob("__init__.py"))


def _takes_arguments(obj) -> bool:
    """Whether ``obj`` (a function, or a class through its constructor) has a parameter to document."""
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):
        return False
    return any(name not in ("self", "cls") for name in signature.parameters)


def _exported(package: str):
    module = importlib.import_module(package)
    for name in getattr(module, "__all__", ()):
        obj = getattr(module, name)
        if (inspect.isfunction(obj) or inspect.isclass(obj)) and obj.__module__.startswith("histostudy"):
            yield name, obj


@pytest.mark.parametrize("package", PACKAGES)
def test_every_exported_function_and_class_documents_its_arguments(package):
    """Google style, as kornia: an ``Args:`` section naming each argument (a dataclass's fields, a
    class's constructor), with its unit and frame where it has one. Exceptions, enums and protocols
    document their members instead."""
    undocumented = []
    for name, obj in _exported(package):
        if inspect.isclass(obj) and (issubclass(obj, (BaseException, int, str)) or getattr(obj, "_is_protocol", False)):
            continue
        doc = inspect.getdoc(obj) or ""
        if not doc:
            undocumented.append(f"{name} (no docstring)")
        elif _takes_arguments(obj) and not re.search(r"^(Args|Attributes|Parameters):", doc, re.M):
            undocumented.append(name)
    assert undocumented == [], f"{package}: exported without an Args: section: {undocumented}"


def test_the_version_lives_in_one_place():
    """``histostudy.__version__`` is the version; pyproject.toml reads it, CITATION.cff repeats it."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["hatch"]["version"] == {"path": "histostudy/__init__.py"}  # hatchling reads it there
    cited = re.search(r"^version: (\S+)$", (REPO / "CITATION.cff").read_text(), re.M).group(1)
    assert cited == histostudy.__version__
    assert re.fullmatch(r"\d+\.\d+\.\d+", histostudy.__version__)
