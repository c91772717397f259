"""The notebooks' one section interface: a notebook's parameters checked into a frozen
``<Section>Config`` (:class:`SectionConfig`), the :class:`SectionPart` its part functions return, and
:func:`record`, which writes parts through a ``SectionWriter``. It imports nothing of the study, nor of
``reporting`` (docs/study-sections.md).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Self, TypeVar

import numpy as np

__all__ = ["STUDY_SPLAT_DEVICES", "RenderedSectionConfig", "SectionConfig", "SectionPart", "Timer", "check_bool",
           "check_choice", "check_splat_device", "check_text", "config_from_parameters", "record", "timer_or_untimed"]

#: The renderers a notebook's ``splat_device`` may name (:data:`histostudy.imaging.SPLAT_DEVICES`):
#: ``"numpy"``, the reference; ``"cpu"``, the compiled kernel; ``"cuda"``, torch; ``"auto"``, CUDA
#: where torch sees one, else compiled.
STUDY_SPLAT_DEVICES = ("numpy", "cpu", "cuda", "auto")

_Config = TypeVar("_Config")

#: ``timer(name)`` -> a context manager timing the block under ``name`` (``SectionWriter.timer``).
Timer = Callable[[str], contextlib.AbstractContextManager]


def timer_or_untimed(timer: Timer | None) -> Timer:
    """``timer``, or one that times nothing.

    Args:
        timer: ``timer(name)`` -> a context manager, or None.

    Returns:
        ``timer``, or a timer whose context managers do nothing.
    """
    return timer or (lambda name: contextlib.nullcontext())


def check_bool(value, name: str) -> bool:
    """``value`` as a bool, if it is True or False (Python or numpy).

    Args:
        value: the value to check.
        name: its name, in the error message.

    Returns:
        ``value`` as a Python bool.

    Raises:
        ValueError: ``value`` is not a bool.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_choice(value, name: str, choices) -> str:
    """``value``, if it is one of the strings ``choices``.

    Args:
        value: the value to check.
        name: its name, in the error message.
        choices: the allowed strings.

    Returns:
        ``value``.

    Raises:
        ValueError: ``value`` is not one of ``choices``.
    """
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def check_splat_device(value) -> str:
    """``value``, if it names one of :data:`STUDY_SPLAT_DEVICES` (a notebook's ``splat_device``).

    Args:
        value: the value to check.

    Returns:
        ``value``.

    Raises:
        ValueError: ``value`` names no renderer.
    """
    return check_choice(value, "splat_device", STUDY_SPLAT_DEVICES)


def check_text(value, name: str, what: str) -> str:
    """``value``, if it is a string.

    Args:
        value: the value to check.
        name: its name, in the error message.
        what: what it must be, in the error message.

    Returns:
        ``value``.

    Raises:
        ValueError: ``value`` is not a string.
    """
    if not isinstance(value, str):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return value


def config_from_parameters(cls: type[_Config], parameters: Mapping, notebook: str) -> _Config:
    """A ``cls`` of the entries of ``parameters`` that name its fields (other entries are ignored).

    Args:
        cls: a dataclass.
        parameters: the notebook's ``globals()``, or any mapping naming every field.
        notebook: the notebook whose parameters cell names the fields (in the error message).

    Returns:
        ``cls(**fields)``.

    Raises:
        TypeError: ``cls`` is not a dataclass.
        ValueError: ``parameters`` lacks a field (each missing one named), or ``cls`` refuses a value.
    """
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"cls={cls!r}: expected a dataclass")
    names = [f.name for f in dataclasses.fields(cls)]
    missing = [name for name in names if name not in parameters]
    if missing:
        raise ValueError(f"parameters lack {missing} (notebook {notebook}'s parameters cell names each)")
    return cls(**{name: parameters[name] for name in names})


class SectionConfig:
    """What every notebook's parameters object shares: it is built from the parameters cell by
    :meth:`from_parameters` and gives the parameters its report records by :meth:`recorded`. A
    subclass is a frozen dataclass that sets the class attributes below and checks its fields in
    ``__post_init__``.

    Attributes:
        NOTEBOOK: the notebook's number, named when a parameter is missing.
        RECORDED: the recorded parameter names, in order; empty: every field.
    """

    NOTEBOOK: ClassVar[str] = ""
    RECORDED: ClassVar[tuple] = ()
    # Declared, not set: every subclass is a dataclass (above), which this lets the type checker see.
    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]

    @classmethod
    def from_parameters(cls, parameters: Mapping) -> Self:
        """The config of the entries of ``parameters`` that name its fields.

        Args:
            parameters: the notebook's ``globals()``, or any mapping naming every field (other
                entries are ignored).

        Returns:
            The checked config.

        Raises:
            ValueError: a missing parameter (named, with the notebook) or a bad value.
        """
        return config_from_parameters(cls, parameters, cls.NOTEBOOK)

    def recorded(self) -> dict:
        """The parameters the report records (``RECORDED``, in that order)."""
        return {name: getattr(self, name) for name in self.RECORDED or [f.name for f in dataclasses.fields(self)]}


@dataclass(frozen=True)
class RenderedSectionConfig(SectionConfig):
    """A :class:`SectionConfig` whose notebook renders frames (§II-B.2); each subclass checks the
    fields in its ``__post_init__``.

    Args:
        photons_per_pixel: unattenuated photons per detector pixel.
        n_splats: splats per model point.
        splat_sigma_mm: splat jitter SD, mm.
        pose_spacing_mm: the pose model's point spacing, mm.
        render_spacing_mm: the rendering model's point spacing, mm.
        background: the background scene.
        splat_device: where the frames are splatted, one of :data:`STUDY_SPLAT_DEVICES`.
    """

    photons_per_pixel: float
    n_splats: int
    splat_sigma_mm: float
    pose_spacing_mm: float
    render_spacing_mm: float
    background: str
    splat_device: str


@dataclass(frozen=True, eq=False)
class SectionPart:
    """What one part of a section reports, as its function made it; :func:`record` writes it, in
    the order of the fields.

    Args:
        tables: name -> ``(DataFrame, caption)`` or ``(DataFrame, caption, options)``, ``options``
            the keywords of ``SectionWriter.table`` (e.g. ``{"digits": 2}``).
        figures: name -> ``(Figure, caption)``.
        values: key -> a JSON-able value.
        comparisons: comparisons with the paper, each the keywords of ``SectionWriter.compare``.
        texts: paragraphs of Markdown.
        stand_ins: ``(lab, synthetic)`` pairs: what stands in for the lab's equipment.
    """

    tables: dict = dataclasses.field(default_factory=dict)
    figures: dict = dataclasses.field(default_factory=dict)
    values: dict = dataclasses.field(default_factory=dict)
    comparisons: tuple = ()
    texts: tuple = ()
    stand_ins: tuple = ()

    def table(self, name: str):
        """The DataFrame of table ``name``.

        Args:
            name: the table's name.

        Returns:
            The DataFrame.

        Raises:
            KeyError: no such table.
        """
        return self.tables[name][0]


def record(writer, *parts) -> None:
    """Write each part's tables, figures, values, comparisons, paragraphs and stand-ins, in that order.

    Args:
        writer: a :class:`histostudy.reporting.SectionWriter`, or any object with its ``table``,
            ``figure``, ``value``, ``compare``, ``text`` and ``stand_in`` methods.
        *parts: :class:`SectionPart` objects, or section results holding one as ``part``.

    Raises:
        TypeError: a part is neither.
    """
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
