"""What every test session prints first: the CPU, its instruction-set flags, any restriction of the
libraries to a lower instruction set (``make test-avx2``) and the numerical libraries' versions, so
that a failure on one machine can be told from a failure on every machine (docs/testing.md); and
the order that lets two workers share the suite: the longest test first. And one fixture:
``notebook_parameters``, a notebook's stored parameters cell."""

import json
from pathlib import Path

import pytest

from histostudy.core.machine import machine_summary


def pytest_report_header(config):
    return machine_summary().splitlines()


def pytest_collection_modifyitems(config, items):
    # pytest-xdist (make test: -n 2 --dist worksteal) hands each worker a contiguous half of the
    # items and lets an idle worker take from the other's queue: with the smoke study first, one
    # worker runs it while the other runs everything else.
    items.sort(key=lambda item: item.get_closest_marker("longest") is None)


@pytest.fixture
def notebook_parameters():
    """``notebook_parameters(name)``: the variables the ``parameters`` cell of ``notebooks/<name>.ipynb``
    sets, as stored (the notebook's defaults)."""
    def read(name: str) -> dict:
        notebook = Path(__file__).resolve().parents[1] / "notebooks" / f"{name}.ipynb"
        (cell,) = [c for c in json.loads(notebook.read_text())["cells"]
                   if "parameters" in c.get("metadata", {}).get("tags", [])]
        namespace: dict = {}
        exec("".join(cell["source"]), namespace)
        return {k: v for k, v in namespace.items() if not k.startswith("__")}

    return read
