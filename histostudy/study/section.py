"""The notebooks' one section interface, shared by every notebook's module (docs/architecture.md,
"Configuration classes"): a notebook's parameters checked into a frozen ``<Section>Config``
(:func:`config_from_parameters`, and the checks :func:`check_bool`, :func:`check_choice`,
:func:`check_text`), a ``prepare`` making its ``<Section>Setup``, pure functions returning
:class:`SectionPart` objects (tables, figures, values, comparisons with the paper, paragraphs and
stand-ins) and :func:`record`, which writes them through a ``SectionWriter``.

The lowest module of :mod:`histostudy.study`: it imports nothing of the study, and nothing of
``reporting`` (a writer is any object with ``SectionWriter``'s methods).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

__all__ = ["RenderedSectionConfig", "SectionConfig", "SectionPart", "Timer", "check_bool", "check_choice",
           "check_text", "config_from_parameters", "record", "timer_or_untimed"]

#: ``timer(name)`` -> a context manager timing the block under ``name`` (``SectionWriter.timer``).
Timer = Callable[[str], contextlib.AbstractContextManager]


def timer_or_untimed(timer: Timer | None) -> Timer:
    """``timer``, or one that times nothing when it is None."""
    return timer or (lambda name: contextlib.nullcontext())


def check_bool(value, name: str) -> bool:
    """``value`` as a bool, if it is True or False (Python or numpy)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_choice(value, name: str, choices) -> str:
    """``value``, if it is one of the strings ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_text(value, name: str, what: str) -> str:
    """``value``, if it is a string (``what`` says which, in the error message)."""
    if not isinstance(value, str):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return value


def config_from_parameters(cls, parameters: Mapping, notebook: str):
    """``cls`` (a dataclass) of the entries of ``parameters`` (the notebook's ``globals()``, or any
    mapping naming every field; other entries are ignored) that name its fields; a missing one is
    named, with the ``notebook`` whose parameters cell names it."""
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [name for name in names if name not in parameters]
    if missing:
        raise ValueError(f"parameters lack {missing} (notebook {notebook}'s parameters cell names each)")
    return cls(**{name: parameters[name] for name in names})


class SectionConfig:
    """What every notebook's parameters object shares (docs/architecture.md, "Configuration
    classes"): it is built from the parameters cell by :meth:`from_parameters` and gives the
    parameters its report records by :meth:`recorded`. A subclass is a frozen dataclass that sets
    ``NOTEBOOK`` (its number, named when a parameter is missing) and ``RECORDED`` (the recorded
    names, in order; empty: every field)."""

    NOTEBOOK: ClassVar[str] = ""
    RECORDED: ClassVar[tuple] = ()

    @classmethod
    def from_parameters(cls, parameters: Mapping):
        """The parameters of ``parameters`` (the notebook's ``globals()``, or any mapping naming every
        field; other entries are ignored)."""
        return config_from_parameters(cls, parameters, cls.NOTEBOOK)

    def recorded(self) -> dict:
        """The parameters the report records (``RECORDED``, in that order)."""
        return {name: getattr(self, name) for name in self.RECORDED or [f.name for f in dataclasses.fields(self)]}


@dataclass(frozen=True)
class RenderedSectionConfig(SectionConfig):
    """A :class:`SectionConfig` whose notebook renders frames (§II-B.2): the unattenuated photons per
    pixel, the splats per model point and their jitter (mm), the pose and render models' point
    spacings (mm) and the background scene. Each subclass checks them in its ``__post_init__``."""

    photons_per_pixel: float
    n_splats: int
    splat_sigma_mm: float
    pose_spacing_mm: float
    render_spacing_mm: float
    background: str


@dataclass(frozen=True, eq=False)
class SectionPart:
    """What one part of a section reports, as its function made it: ``tables`` (name ->
    ``(DataFrame, caption)`` or ``(DataFrame, caption, options)``, ``options`` the keywords of
    ``SectionWriter.table``, e.g. ``{"digits": 2}``), ``figures`` (name -> ``(Figure, caption)``),
    ``values`` (key -> JSON-able), ``comparisons`` with the paper (``SectionWriter.compare``
    keywords), ``texts`` (paragraphs of Markdown) and ``stand_ins`` (``(lab, synthetic)`` pairs).
    Written by :func:`record`, in that order."""

    tables: dict = dataclasses.field(default_factory=dict)
    figures: dict = dataclasses.field(default_factory=dict)
    values: dict = dataclasses.field(default_factory=dict)
    comparisons: tuple = ()
    texts: tuple = ()
    stand_ins: tuple = ()

    def table(self, name: str):
        """The DataFrame of table ``name``."""
        return self.tables[name][0]


def record(writer, *parts) -> None:
    """Write each of ``parts`` (a :class:`SectionPart`, or a section result holding one as ``part``)
    through ``writer`` (a :class:`histostudy.reporting.SectionWriter`): its tables, figures, values,
    comparisons, paragraphs and stand-ins."""
    for part in parts:
        part = getattr(part, "part", part)
        if not isinstance(part, SectionPart):
            raise TypeError(f"parts must be SectionPart objects or hold one as .part, got {type(part).__name__}")
        for name, (table, caption, *options) in part.tables.items():
            writer.table(name, table, caption, **(options[0] if options else {}))
        for name, (figure, caption) in part.figures.items():
            writer.figure(name, figure, caption)
        for key, value in part.values.items():
            writer.value(key, value)
        for comparison in part.comparisons:
            writer.compare(**comparison)
        for paragraph in part.texts:
            writer.text(paragraph)
        for lab, synthetic in part.stand_ins:
            writer.stand_in(lab, synthetic)
