"""The magnitudes without a measurement swept over their plausible range (§IV): lab 0 run again
with one ``swept`` source at each end of its range, everything else as lab 0 has it. C-arm frame,
mm (docs/error-budget.md, "The swept sources as bands").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ..section import SectionPart, Timer, timer_or_untimed
from ._distribution import lab_statistics
from ._labs import run_labs
from ._references import SOURCE_REFERENCES, model_at
from ._run import BudgetSetup, section_params, section_seeds
from ._sources import LAB_SOURCES, LabDraw, draw_lab

__all__ = ["FRAME_SOURCES", "RANGE_ENDS", "RangesSection", "range_bands", "range_labs", "ranges_section",
           "run_ranges"]

#: The sources that change the frames themselves (the transducer imaged, where the source stands):
#: a lab with one of them at another magnitude renders its own frames.
FRAME_SOURCES = ("manufacturing", "gantry_sag", "robot_accuracy")

#: The ends of a source's range that are run, as the reference names them.
RANGE_ENDS = ("low", "high")


def range_labs(setup: BudgetSetup, sources: Sequence[str]) -> list[tuple[str, str, float, LabDraw]]:
    """``(source, end, value, lab)`` for each of ``sources`` (on in the set-up's lab model) at each
    end of its range (:data:`RANGE_ENDS`, the reference's unit): lab 0's draw with that source's
    magnitude set there (:func:`~._references.model_at`). A source outside :data:`FRAME_SOURCES`
    keeps lab 0's transducer and true views (the same objects), so that its frames are shared."""
    base = setup.lab
    sources = list(sources)
    off = [s for s in sources if s not in LAB_SOURCES or getattr(base.model, s) is None]
    if off or len(set(sources)) != len(sources):
        raise ValueError(f"sources must name sources on in the lab model ({', '.join(base.model.enabled)}), "
                         f"each at most once, got {sources!r}")
    out = []
    for name in sources:
        ref = SOURCE_REFERENCES[name]
        for end in RANGE_ENDS:
            value = float(getattr(ref, end))
            lab = draw_lab(model_at(name, value, base=base.model), base.seed, physical=base.study_physical,
                           views=base.study_views, physical_seed=section_seeds(setup).physical)
            if name not in FRAME_SOURCES:
                if not (np.array_equal(lab.physical.focal_point_mm, base.physical.focal_point_mm)
                        and all(np.array_equal(a.P, b.P) for a, b in zip(lab.frame_views, base.frame_views))):
                    raise RuntimeError(f"source {name!r} at {value:g} moved lab 0's frames; it belongs in "
                                       "FRAME_SOURCES")
                lab = dataclasses.replace(lab, physical=base.physical, frame_views=base.frame_views)
            out.append((name, end, value, lab))
    return out


def run_ranges(setup: BudgetSetup, sources: Sequence[str], *, executor=None) -> pd.DataFrame:
    """Run every lab of :func:`range_labs` (lab 0 with one source at each end of its range) on the
    set-up's experiments and the study seed (:func:`~histostudy.study.budget._labs.run_labs`); the labs
    that keep lab 0's frames run together, sharing renders and segmentations. A pose experiment runs
    its centre only: the bands (:func:`range_bands`) read the centre's Euclidean error alone, and
    the centre's numbers are those of the whole experiment.

    Args:
        setup: the budget's set-up (from notebook 07's ``prepare``: its lab, seeds and params).
        sources: the swept sources (names of :data:`~histostudy.study.budget.LAB_SOURCES`, each on in lab 0).
        executor: what runs the tasks (:func:`histostudy.core.run_sweep`); None: the default.

    Returns:
        ``run_labs``' rows with ``source``, ``end`` and ``value`` in front (``lab`` from 1 in
        :func:`range_labs`' order).

    Raises:
        ValueError: a source not swept or not on in lab 0 (:func:`range_labs`), or ``setup`` without
            ``seeds``.
    """
    labs = range_labs(setup, sources)
    if not labs:
        return pd.DataFrame(columns=["source", "end", "value", "lab", "study", "experiment"])
    shared = [i for i, (name, *_) in enumerate(labs) if name not in FRAME_SOURCES]
    own = [i for i, (name, *_) in enumerate(labs) if name in FRAME_SOURCES]
    frames = []
    for group in (shared, own):
        if group:
            frames.append(run_labs(setup, [labs[i][3] for i in group], seed=section_seeds(setup).study,
                                   indices=[i + 1 for i in group], executor=executor, centre_only=True))
    out = pd.concat(frames, ignore_index=True).sort_values(["lab", "study", "experiment"], kind="stable")
    meta = {i + 1: (name, end, value) for i, (name, end, value, _) in enumerate(labs)}
    for position, column in enumerate(("source", "end", "value")):
        out.insert(position, column, [meta[int(k)][position] for k in out["lab"]])
    return out.reset_index(drop=True)


def range_bands(range_records: pd.DataFrame, budget_records: pd.DataFrame) -> pd.DataFrame:
    """Per swept source and study: the Euclidean mean (mm) of lab 0 at the source's low end, at its
    default (lab 0's "lab" configuration in ``budget_records``) and at its high end, the band's
    width ``band_mm`` (the largest of the three less the smallest: a lab's figure need not be
    monotone in a source, its draws being fixed; NaN ends, a study with no result, left out), and
    the source's status, unit and range; the rows of :func:`run_ranges`."""
    lab0 = budget_records[budget_records["configuration"] == "lab"].assign(lab=0)
    at_default = lab_statistics(lab0).set_index("study")["euclidean_mean_mm"]
    if range_records.empty:
        return pd.DataFrame(columns=["source", "study", "status", "unit", "low", "default", "high", "at_low_mm",
                                     "at_default_mm", "at_high_mm", "band_mm"])
    stats = lab_statistics(range_records.drop(columns=["source", "end", "value"])).set_index(["lab", "study"])
    meta = range_records.drop_duplicates("lab").set_index("lab")[["source", "end", "value"]]
    rows = []
    for source in dict.fromkeys(meta["source"]):
        ref = SOURCE_REFERENCES[source]
        ends = {row.end: lab for lab, row in meta[meta["source"] == source].iterrows()}
        for study in at_default.index:
            low = float(stats.loc[(ends["low"], study), "euclidean_mean_mm"])
            high = float(stats.loc[(ends["high"], study), "euclidean_mean_mm"])
            rows.append({"source": source, "study": study, "status": ref.status, "unit": ref.unit, "low": ref.low,
                         "default": ref.value, "high": ref.high, "at_low_mm": low,
                         "at_default_mm": float(at_default[study]), "at_high_mm": high,
                         "band_mm": _spread_mm((low, float(at_default[study]), high))})
    return pd.DataFrame(rows)


def _spread_mm(values) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return float(max(finite) - min(finite)) if len(finite) >= 2 else float("nan")


@dataclasses.dataclass(frozen=True, eq=False)
class RangesSection:
    """The swept sources (:func:`ranges_section`): the runs' ``records``, the ``bands`` and the
    report's ``part``."""

    records: pd.DataFrame
    bands: pd.DataFrame
    part: SectionPart


def ranges_section(setup: BudgetSetup, budget_records: pd.DataFrame, *, timer: Timer | None = None) -> RangesSection:
    """Notebook 07's part: ``setup.params.range_sources`` at both ends of their ranges on lab 0
    (:func:`run_ranges` on ``params.scheduler``, timed as ``"ranges"``).

    Args:
        setup: the budget's set-up (notebook 07's ``prepare``).
        budget_records: :func:`~histostudy.study.budget.run_error_budget`'s rows (lab 0's figures).
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`RangesSection`: the bands (:func:`range_bands`, mm) and the part (table ``ranges``
        and a paragraph naming the widest).

    Raises:
        ValueError: ``setup`` has no ``params`` or ``seeds`` (not made by notebook 07's ``prepare``).
    """
    params = section_params(setup)
    with timer_or_untimed(timer)("ranges"):
        records = run_ranges(setup, params.range_sources, executor=params.scheduler or None)
    bands = range_bands(records, budget_records)
    if bands.empty:
        text = "No source was run over its range (`range_sources` is empty)."
    else:
        parts = []
        for study, g in bands.groupby("study", sort=False):
            top = g.sort_values("band_mm", ascending=False).iloc[0]
            parts.append(f"{'Table II' if study == 'pose' else 'targeting'}: the widest band is {top['source']}'s, "
                         f"{top['at_low_mm']:.2f} to {top['at_high_mm']:.2f} mm over {top['low']:g}-{top['high']:g} "
                         f"{top['unit']} (lab 0 at its default: {top['at_default_mm']:.2f} mm)")
        text = ("Each source run over its range moves lab 0's Euclidean mean error within the band shown; every "
                "other source and every draw stays as lab 0 has them. " + "; ".join(parts) + ".")
    part = SectionPart(
        tables={"ranges": (bands, "The sources without a fitting measurement, each at both ends of its plausible "
                           "range on lab 0 (the others at their defaults): the Euclidean mean error (mm) at the low "
                           "end, at the default and at the high end, and the band's width", {"digits": 2})},
        values={"ranges_sources": list(params.range_sources)}, texts=(text,))
    return RangesSection(records, bands, part)
