"""The argument checks every layer's configurations and entry points share.

A bad argument is refused at the call with a ValueError that names the argument, its value and what
was expected; these helpers write that message once so that every configuration words it the same
way. ``bool`` is never a number here (``True`` as a length is a bug, not 1 mm).
"""

from __future__ import annotations

import math
import numbers

__all__ = ["check_count", "check_items", "check_positive", "check_unit_fraction", "is_finite_real", "is_real"]


def is_real(value) -> bool:
    """True for a Python or numpy real number (int or float kinds), False for ``bool`` and the rest."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_finite_real(value) -> bool:
    """:func:`is_real` and finite (no NaN, no infinity)."""
    return is_real(value) and math.isfinite(float(value))


def check_positive(value, name: str, *, allow_zero: bool = False, unit: str = "") -> float:
    """``value`` as a float, if it is a finite real number > 0 (>= 0 with ``allow_zero``).

    ``unit`` (e.g. ``"mm"``) is named in the error message only.
    """
    if not is_finite_real(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}{' ' + unit if unit else ''}, got {value!r}")
    return float(value)


def check_count(value, name: str, *, minimum: int = 1) -> int:
    """``value`` as an int, if it is an integer (Python or numpy, not bool) >= ``minimum``."""
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_unit_fraction(value, name: str = "scale") -> int:
    """The integer ``k`` of a scale ``value`` = 1/k (1, 0.5, 0.25, ...), the reductions a label image
    or a detector region may be resampled by; anything else is refused."""
    try:
        scale = float(value)
    except (TypeError, ValueError):
        scale = float("nan")
    k = int(round(1.0 / scale)) if math.isfinite(scale) and scale > 0 else 0
    if isinstance(value, bool) or k < 1 or abs(k * scale - 1.0) > 1e-9:
        raise ValueError(f"{name} must be 1/k for an integer k >= 1 (1, 0.5, 0.25, ...), got {value!r}")
    return k


def check_items(values, name: str, item_type: type, *, type_name: str | None = None) -> list:
    """``values`` — one ``item_type`` or an iterable of them — as a non-empty list; an empty one
    raises ValueError, an item of another type TypeError naming its index (``type_name``: how the
    message names ``item_type``, default its qualified name)."""
    shown = type_name or f"{item_type.__module__}.{item_type.__qualname__}"
    items = [values] if isinstance(values, item_type) else list(values)
    if not items:
        raise ValueError(f"{name} must hold at least one {item_type.__name__}, got none")
    for i, item in enumerate(items):
        if not isinstance(item, item_type):
            raise TypeError(f"{name}[{i}] must be a {shown}, got {type(item).__name__}: {item!r:.80}")
    return items
