"""What every test session prints first: the CPU, its instruction-set flags, any restriction of the
libraries to a lower instruction set (``make test-avx2``) and the numerical libraries' versions, so
that a failure on one machine can be told from a failure on every machine (docs/testing.md); and
the order that lets two workers share the suite: the longest test first. And the fixtures:
``notebook_parameters``, a notebook's stored parameters cell, ``stage_clock``, the stage profile's
clocks stepped by the test, and the logging state restored after each test (``histostudy.cli.main``
sets it for its process)."""

import contextlib
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


@pytest.fixture
def assert_parameter_refused():
    """``assert_parameter_refused(config_class, defaults, name, value, expected)``: the section config
    made of ``defaults`` with ``name`` set to ``value`` raises a ValueError that starts with the
    parameter's name and holds the value and ``expected`` (what the value must be); and the
    config's ``from_parameters`` without ``name`` names it as missing, with the notebook."""
    def check(config_class, defaults: dict, name: str, value, expected: str) -> None:
        with pytest.raises(ValueError) as info:
            config_class(**{**defaults, name: value})
        message = str(info.value)
        assert message.startswith(f"{name} must ") and expected in message and repr(value) in message
        with pytest.raises(ValueError, match=rf"parameters lack \['{name}'\] \(notebook "):
            config_class.from_parameters({k: v for k, v in defaults.items() if k != name})

    return check


@pytest.fixture
def recording_timer():
    """``timer, timed = recording_timer()``: a context manager like ``SectionWriter.timer`` that
    appends each name it times to the list ``timed``."""
    def make():
        timed = []

        @contextlib.contextmanager
        def timer(name):
            timed.append(name)
            yield

        return timer, timed

    return make


@pytest.fixture
def stage_clock(monkeypatch):
    """The clocks of :mod:`histostudy.core.stage_profile` replaced by ones that move only when the test
    says, ``stage_clock.tick(wall_s, cpu_s=wall_s)``, so that stage times are exact figures."""
    from histostudy.core import stage_profile

    class SteppedClock:
        wall = cpu = 0.0

        def tick(self, wall_s, cpu_s=None):
            self.wall += wall_s
            self.cpu += wall_s if cpu_s is None else cpu_s

    clock = SteppedClock()
    monkeypatch.setattr(stage_profile, "wall_clock", lambda: clock.wall)
    monkeypatch.setattr(stage_profile, "cpu_clock", lambda: clock.cpu)
    return clock


@pytest.fixture(autouse=True)
def _logging_as_it_was():
    """``histostudy.cli.main`` sets the ``histostudy`` loggers' levels and stderr handler for its
    process (-q/-v); a test that calls it in this process must not change what later tests log."""
    import logging

    loggers = [logging.getLogger(name) for name in ("histostudy", "histostudy.cli")]
    saved = [(lg, lg.level, list(lg.handlers)) for lg in loggers]
    yield
    for lg, level, handlers in saved:
        lg.setLevel(level)
        lg.handlers[:] = handlers
