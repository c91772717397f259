"""Every notebook's section has one shape (docs/architecture.md, "Notebook sections"): a folder under
``histostudy/study/`` whose ``__init__`` gives one ``<Section>Config`` built from the parameters cell,
a ``prepare`` making its set-up, part functions returning tables and figures, and ``record``, which
the notebook calls to write them."""

from __future__ import annotations

import importlib
import inspect
import json
import re
from pathlib import Path

import pytest

import histostudy
from histostudy.study import section

REPO = Path(histostudy.__file__).parent.parent
NOTEBOOKS = sorted((REPO / "notebooks").glob("[0-9][0-9]_*.ipynb"))


def _code(path: Path) -> str:
    cells = json.loads(path.read_text())["cells"]
    return "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")


def test_there_are_seven_notebooks():
    assert [p.name[:2] for p in NOTEBOOKS] == ["01", "02", "03", "04", "05", "06", "07"]


@pytest.mark.parametrize("notebook", NOTEBOOKS, ids=lambda p: p.stem)
def test_each_notebook_s_section_has_the_same_three_parts(notebook):
    code = _code(notebook)
    imported = re.findall(r"from histostudy\.study import (\w+) as study\b", code)
    assert len(imported) == 1, f"{notebook.name} imports its section as `study` once, got {imported}"
    module = importlib.import_module(f"histostudy.study.{imported[0]}")
    assert Path(module.__file__).name == "__init__.py", f"{module.__name__} is a module, not a folder"

    exported = {name: getattr(module, name) for name in module.__all__}
    configs = [name for name, obj in exported.items()
               if inspect.isclass(obj) and issubclass(obj, section.SectionConfig)]
    assert len(configs) == 1 and configs[0].endswith("Config"), f"{module.__name__}: configs {configs}"
    assert exported[configs[0]].NOTEBOOK == notebook.name[:2]
    assert callable(exported.get("prepare")), f"{module.__name__} has no prepare"
    assert exported.get("record") is section.record, f"{module.__name__} does not give section.record"

    assert f"study.{configs[0]}.from_parameters(" in code
    assert "study.prepare(" in code and "study.record(" in code
    used = set(re.findall(r"(?<![\w.])study\.(\w+)", code))
    unexported = used - set(module.__all__)
    assert unexported == set(), f"{notebook.name} calls what its section does not export: {unexported}"
    parts = used - {configs[0], "prepare", "record"} - {n for n in used if n.isupper()}
    assert parts, f"{notebook.name} calls no part function"
