"""The house's measurable rules (docs/architecture.md, "Layers"): functions that fit on a screen, docs
that describe what is, and no timing figure outside benchmarks/ and the docs' tables (machines differ;
a figure in a docstring goes stale without anyone rerunning it). A module's size follows its job: no
rule counts its lines."""

import ast
import re
from pathlib import Path

import histostudy

PACKAGE = Path(histostudy.__file__).parent
REPO = PACKAGE.parent

#: A duration in milli- or microseconds, or a speed-up factor: what a docstring must not carry.
#: DICOM's FrameTime (ms) is a unit, not a measurement, and stays allowed.
TIMING = re.compile(r"\d\s?(ms|µs)\b|\d\s?[x×]\s(faster|slower)|core-ms")


def _sources():
    return sorted(PACKAGE.rglob("*.py"))


def test_no_function_over_100_lines():
    """Its code, that is: the docstring is reference, as long as its arguments need."""
    long = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if ast.get_docstring(node) is not None:
                    docstring = node.body[0]
                    length -= docstring.end_lineno - docstring.lineno + 1
                if length > 100:
                    long.append(f"{path.relative_to(REPO)}:{node.lineno} {node.name} ({length} lines)")
    assert long == []


def test_no_timing_figure_in_a_docstring_or_comment():
    found = []
    for path in _sources():
        source = path.read_text()
        texts = []
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                texts += (ast.get_docstring(node) or "").splitlines()
        texts += [line.split("#", 1)[1] for line in source.splitlines() if "#" in line]
        found += [f"{path.relative_to(REPO)}: {t.strip()}" for t in texts
                  if TIMING.search(t) and "FrameTime" not in t and "frame_time" not in t]
    assert found == []


def test_no_doc_over_400_lines():
    long = [f"{p.name}: {n}" for p in sorted((REPO / "docs").glob("*.md"))
            if (n := len(p.read_text().splitlines())) > 400]
    assert long == []


def test_notebooks_call_only_public_names_their_modules_export():
    """A notebook's ``from histostudy... import x as alias`` then ``alias.name``: each name is public
    (no leading underscore) and in the module's ``__all__``, so a split of the module cannot drop it."""
    import importlib
    import json

    missing = []
    for path in sorted((REPO / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        for package, name, alias in re.findall(r"from (histostudy[\w.]*) import (\w+) as (\w+)", code):
            module = importlib.import_module(f"{package}.{name}")
            for used in sorted(set(re.findall(rf"(?<![\w.]){alias}\.(\w+)", code))):
                if used.startswith("_") or used not in getattr(module, "__all__", ()):
                    missing.append(f"{path.name}: {alias}.{used} ({module.__name__})")
    assert missing == []
