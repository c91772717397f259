"""The argument checks every layer's configurations and entry points share: each refuses a bad
argument with a ValueError (or TypeError) naming the argument, its value and what was expected.
Arguments come in one order everywhere: the value first, then its name. ``bool`` is never a number
here (``True`` as a length is a bug, not 1 mm).
"""

from __future__ import annotations

import math
import numbers
from typing import Literal, overload

__all__ = ["check_ae_title", "check_count", "check_host", "check_items", "check_port", "check_positive",
           "check_unit_fraction", "is_finite_real", "is_real"]


def is_real(value) -> bool:
    """Whether ``value`` is a real number.

    Args:
        value: anything.

    Returns:
        True for a Python or numpy real number (int or float kinds); False for ``bool`` and the rest.
    """
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_finite_real(value) -> bool:
    """Whether ``value`` is a finite real number.

    Args:
        value: anything.

    Returns:
        :func:`is_real` and finite (no NaN, no infinity).
    """
    return is_real(value) and math.isfinite(float(value))


@overload
def check_positive(value, name: str, *, allow_zero: bool = ..., unit: str = ..., optional: Literal[False] = ...,
                   what: str | None = ...) -> float: ...
@overload
def check_positive(value, name: str, *, allow_zero: bool = ..., unit: str = ..., optional: bool,
                   what: str | None = ...) -> float | None: ...
def check_positive(value, name: str, *, allow_zero: bool = False, unit: str = "", optional: bool = False,
                   what: str | None = None) -> float | None:
    """``value`` as a float, if it is a finite real number > 0 (>= 0 with ``allow_zero``).

    Args:
        value: the argument to check.
        name: the argument's name, for the message.
        allow_zero: accept 0 as well.
        unit: the unit (e.g. ``"mm"``), named in the message only.
        optional: accept None as well (returned as is).
        what: what ``value`` must be, for the message (e.g. ``"a finite number of seconds > 0"``);
            default: ``"a finite number > 0"`` (``>= 0`` with ``allow_zero``) followed by ``unit``.

    Returns:
        ``float(value)``; None where ``value`` is None and ``optional``.

    Raises:
        ValueError: ``value`` is not a finite real number above the bound (nor None where
            ``optional``); the message names ``name``, ``value`` and what was expected.
    """
    if value is None and optional:
        return None
    if not is_finite_real(value) or value < 0 or (value == 0 and not allow_zero):
        if what is None:
            what = f"a finite number {'>= 0' if allow_zero else '> 0'}{' ' + unit if unit else ''}"
        raise ValueError(f"{name} must be {'None or ' if optional else ''}{what}, got {value!r}")
    return float(value)


@overload
def check_count(value, name: str, *, minimum: int = ..., optional: Literal[False] = ...) -> int: ...
@overload
def check_count(value, name: str, *, minimum: int = ..., optional: bool) -> int | None: ...
def check_count(value, name: str, *, minimum: int = 1, optional: bool = False) -> int | None:
    """``value`` as an int, if it is an integer (Python or numpy, not bool) >= ``minimum``.

    Args:
        value: the argument to check.
        name: the argument's name, for the message.
        minimum: the smallest count accepted.
        optional: accept None as well (returned as is; e.g. "no limit").

    Returns:
        ``int(value)``; None where ``value`` is None and ``optional``.

    Raises:
        ValueError: ``value`` is not an integer >= ``minimum`` (nor None where ``optional``).
    """
    if value is None and optional:
        return None
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name} must be {'None or ' if optional else ''}an integer >= {minimum}, got {value!r}")
    return int(value)


def check_unit_fraction(value, name: str = "scale") -> int:
    """The integer ``k`` of a scale ``value`` = 1/k (1, 0.5, 0.25, ...), the reductions a label image
    or a detector region may be resampled by.

    Args:
        value: the scale (a real number).
        name: the argument's name, for the message.

    Returns:
        ``k`` (an int >= 1).

    Raises:
        ValueError: ``value`` is not 1/k for an integer k >= 1.
    """
    try:
        scale = float(value)
    except (TypeError, ValueError):
        scale = float("nan")
    k = int(round(1.0 / scale)) if math.isfinite(scale) and scale > 0 else 0
    if isinstance(value, bool) or k < 1 or abs(k * scale - 1.0) > 1e-9:
        raise ValueError(f"{name} must be 1/k for an integer k >= 1 (1, 0.5, 0.25, ...), got {value!r}")
    return k


def check_items(values, name: str, item_type: type, *, type_name: str | None = None) -> list:
    """``values`` — one ``item_type`` or an iterable of them — as a non-empty list.

    Args:
        values: one ``item_type`` object, or an iterable of them.
        name: the argument's name, for the message.
        item_type: the type each item must have.
        type_name: how the message names ``item_type``; default its qualified name.

    Returns:
        The items, as a list.

    Raises:
        ValueError: ``values`` holds no item.
        TypeError: an item is not an ``item_type``; the message names its index.
    """
    shown = type_name or f"{item_type.__module__}.{item_type.__qualname__}"
    items = [values] if isinstance(values, item_type) else list(values)
    if not items:
        raise ValueError(f"{name} must hold at least one {item_type.__name__}, got none")
    for i, item in enumerate(items):
        if not isinstance(item, item_type):
            raise TypeError(f"{name}[{i}] must be a {shown}, got {type(item).__name__}: {item!r:.80}")
    return items


def check_ae_title(value, name: str = "ae_title") -> str:
    """A DICOM application entity (AE) title, stripped.

    Args:
        value: the title: 1-16 ASCII characters (after stripping spaces), no backslash.
        name: the argument's name, for the message.

    Returns:
        ``value`` without leading and trailing spaces.

    Raises:
        ValueError: ``value`` is not such a string.
    """
    if not isinstance(value, str) or not 1 <= len(value.strip()) <= 16 or not value.isascii() or "\\" in value:
        raise ValueError(f"{name} must be 1-16 ASCII characters without a backslash, got {value!r}")
    return value.strip()


def check_port(value, name: str = "port", *, allow_zero: bool = True) -> int:
    """A TCP port number.

    Args:
        value: the port: an integer (Python or numpy, not bool) in 1..65535, or 0 (any free port)
            where ``allow_zero``.
        name: the argument's name, for the message.
        allow_zero: accept 0 (a listener's "any free port"); a sender's port must be given.

    Returns:
        ``int(value)``.

    Raises:
        ValueError: ``value`` is not such an integer.
    """
    low = 0 if allow_zero else 1
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or not low <= int(value) <= 65535:
        raise ValueError(f"{name} must be an integer in {low}..65535" + (" (0: any free port)" if allow_zero else "")
                         + f", got {value!r}")
    return int(value)


def check_host(value, name: str = "host") -> str:
    """A host name or IP address, stripped.

    Args:
        value: the host: a non-empty string (e.g. ``"127.0.0.1"``).
        name: the argument's name, for the message.

    Returns:
        ``value`` without leading and trailing spaces.

    Raises:
        ValueError: ``value`` is not a non-empty string.
    """
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} must be a host name or address, e.g. '127.0.0.1', got {value!r}")
    return value.strip()
