"""How a reproduced number stands against the paper's (:func:`judge`): the difference, in the
paper's unit, and one status (agrees, differs, far off, not judged) against a tolerance taken from
the paper's SD or its printed digits (docs/report.md, "How the status is decided")."""

from __future__ import annotations

import re
from dataclasses import dataclass

from histostudy.core import is_finite_real

from .paper import PaperValue

__all__ = ["AGREES", "DIFFERS", "FAR_OFF", "FAR_OFF_SD", "NOT_JUDGED", "Agreement", "judge"]

AGREES, DIFFERS, FAR_OFF, NOT_JUDGED = "agrees", "differs", "far off", "not judged"
#: Beyond this many of the paper's SDs a difference is "far off".
FAR_OFF_SD = 3.0

_UNIT_ALIASES = {"°": "deg", "degrees": "deg", "degree": "deg"}
_NUMBER = re.compile(r"[-+−]?\d+(?:\.(\d+))?")
_FLOAT = r"[-+−]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+−]?\d+)?"
_INTERVAL = re.compile(rf"^\s*\[\s*({_FLOAT})\s*,\s*({_FLOAT})\s*\]")
_BOUND = re.compile(rf"^\s*([<>]=?)\s*({_FLOAT})\s*$")


@dataclass(frozen=True)
class Agreement:
    """One reproduced number against the paper's.

    ``status``: :data:`AGREES`, :data:`DIFFERS`, :data:`FAR_OFF` or :data:`NOT_JUDGED`.
    ``difference``: reproduced minus paper, in ``unit`` (None when not computed). ``tolerance``:
    what the difference is judged against, in ``unit``, an SD when ``sd_based``; ``basis`` says
    what it is (or, when not judged, why). ``decimals``: those the reproduced value was printed with.
    """

    status: str
    difference: float | None = None
    tolerance: float | None = None
    basis: str = ""
    unit: str = ""
    decimals: int = 2
    sd_based: bool = False

    @property
    def n_sd(self) -> float | None:
        """``|difference|`` in SDs, where the tolerance is an SD; else None."""
        if self.difference is None or not self.tolerance or not self.sd_based:
            return None
        return abs(self.difference) / self.tolerance

    def difference_text(self) -> str:
        """``"+23.57 deg"``; ``"—"`` when there is no difference."""
        if self.difference is None:
            return "—"
        rounded = round(self.difference, self.decimals)
        text = f"{0.0:.{self.decimals}f}" if rounded == 0 else f"{rounded:+.{self.decimals}f}"
        return f"{text} {self.unit}".strip()

    def summary(self) -> str:
        """The status with its measure and, beyond the tolerance, its direction:
        ``"far off (33 SD above)"``, ``"agrees (0.3 SD)"``, ``"agrees (at the paper's rounding)"``."""
        if self.status == NOT_JUDGED:
            return f"not judged: {self.basis}"
        n = self.n_sd
        if n is None or self.difference is None:
            return f"{self.status} ({self.basis})"
        side = "" if self.status == AGREES else (" above" if self.difference > 0 else " below")
        return f"{self.status} ({n:.1f} SD{side})" if n < 10 else f"{self.status} ({n:.0f} SD{side})"


def judge(comparison: dict, paper: PaperValue, *, twin: PaperValue | None = None) -> Agreement:
    """Judge one recorded comparison (``SectionWriter.compare``'s row: ``ours``, ``unit``,
    ``ours_text``) against the paper's value; ``twin``: the Table II value ``paper`` repeats, whose
    SD is the tolerance when ``paper`` has none."""
    ours, theirs = comparison.get("ours"), paper.mean
    if isinstance(theirs, str):
        return _judge_text(ours, theirs)
    if not is_finite_real(ours):
        why = "no reproduced number" if ours is None else f"the reproduced value is text ({ours!r})"
        return Agreement(NOT_JUDGED, basis=why)
    if not is_finite_real(theirs):
        return Agreement(NOT_JUDGED, basis=f"the paper's value is text ({theirs!r})")
    unit_ours, unit_paper = _unit(comparison.get("unit", "")), _unit(paper.unit)
    if unit_ours and unit_paper and unit_ours != unit_paper:
        return Agreement(NOT_JUDGED, basis=f"units differ ({unit_ours} here, {unit_paper} in the paper)")
    difference = float(ours) - float(theirs)  # type: ignore[arg-type]  # both finite reals, checked above
    unit, decimals = unit_paper or unit_ours, _decimals(comparison.get("ours_text", ""))
    sd_based = True
    if paper.sd:
        tolerance, basis = float(paper.sd), "the paper's SD"
    elif twin is not None and twin.sd:
        tolerance, basis = float(twin.sd), f"the SD of its {twin.where} twin"
    else:
        tolerance, basis, sd_based = 0.5 * 10.0 ** -_decimals(f"{float(theirs):g}"), "at the paper's rounding", False
    if abs(difference) <= tolerance * (1 + 1e-9):
        status = AGREES
    elif sd_based and abs(difference) > FAR_OFF_SD * tolerance:
        status = FAR_OFF
    else:
        status = DIFFERS
    if status != AGREES and not sd_based:
        basis = "the paper gives no SD"
    return Agreement(status, difference, tolerance, basis, unit, decimals, sd_based)


def _judge_text(ours, theirs: str) -> Agreement:
    """The paper's value is text: an interval ``"[a, b]"`` (against a reproduced interval) or a
    bound ``"< x"`` (against a reproduced number, or a number written as text)."""
    paper_interval, paper_bound = _INTERVAL.match(theirs), _BOUND.match(theirs)
    ours_interval = _INTERVAL.match(ours) if isinstance(ours, str) else None
    if paper_interval and ours_interval:
        lo1, hi1 = sorted(_float(x) for x in ours_interval.groups())
        lo2, hi2 = sorted(_float(x) for x in paper_interval.groups())
        if max(lo1, lo2) <= min(hi1, hi2):
            return Agreement(AGREES, basis="the intervals overlap")
        return Agreement(DIFFERS, basis="the intervals are disjoint")
    value = ours if is_finite_real(ours) else _parse_float(ours)
    if paper_bound and value is not None:
        op, bound = paper_bound.group(1), _float(paper_bound.group(2))
        holds = {"<": value < bound, "<=": value <= bound, ">": value > bound, ">=": value >= bound}[op]
        return Agreement(AGREES if holds else DIFFERS, basis=f"{value:g} {'meets' if holds else 'misses'} the "
                         f"paper's bound {theirs.strip()}")
    if ours is None:
        return Agreement(NOT_JUDGED, basis="no reproduced value")
    return Agreement(NOT_JUDGED, basis="text: compare by eye")


def _parse_float(text) -> float | None:
    if not isinstance(text, str) or not re.fullmatch(_FLOAT, text.strip()):
        return None
    return _float(text.strip())


def _float(text: str) -> float:
    return float(text.replace("−", "-"))


def _unit(unit) -> str:
    unit = str(unit or "").strip()
    return _UNIT_ALIASES.get(unit, unit)


def _decimals(text: str) -> int:
    """Decimals of the first number in ``text`` (2 when there is none)."""
    m = _NUMBER.search(str(text))
    if not m:
        return 2
    return len(m.group(1) or "")
