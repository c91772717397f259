"""Notebook 07's many labs (§III, §IV): the labs drawn from the set-up (:func:`prepare_labs`), run
and set beside the paper (:func:`labs_section`): the table "paper vs labs (median, 5-95 %)" per
study, metric and direction in both sign readings, the bias/scatter split, the signs, and which
systematic sources move each figure; each part recorded by :func:`~histostudy.study.section.record`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..pose.geometry import DIRECTIONS
from ..section import SectionPart, Timer, timer_or_untimed
from ._distribution import (
    BAND_PERCENT,
    MOVER_METRICS,
    NATIVE_READING,
    bias_scatter_split,
    lab_statistics,
    labs_vs_paper,
    paper_statistics,
    sign_agreement,
    source_movers,
)
from ._labs import draw_labs, lab_magnitudes, labs_records, run_labs
from ._run import BudgetSetup, section_params, section_seeds
from ._sources import LabDraw

__all__ = ["LabsSection", "labs_figure", "labs_section", "labs_text", "movers_table", "prepare_labs"]


def prepare_labs(setup: BudgetSetup) -> list[LabDraw]:
    """The labs of the distribution (:func:`~histostudy.study.budget.draw_labs`): ``setup.params.n_labs``
    labs of the set-up's lab model from its lab seed, on the study's transducer and views.

    Args:
        setup: the budget's set-up (notebook 07's ``prepare``).

    Returns:
        The labs; lab 0 is ``setup.lab``'s draw.

    Raises:
        ValueError: ``setup`` has no ``params`` or ``seeds`` (not made by notebook 07's ``prepare``).
    """
    lab, seeds = setup.lab, section_seeds(setup)
    return draw_labs(lab.model, seeds.lab, section_params(setup).n_labs, physical=lab.study_physical,
                     views=lab.study_views, physical_seed=seeds.physical)


def movers_table(movers: pd.DataFrame) -> pd.DataFrame:
    """Per (study, metric): the systematic source whose drawn size explains most of the labs'
    spread of the metric (largest ``r²`` of :func:`~._distribution.source_movers`), its ``r`` and
    slope per SD, and the runner-up."""
    rows = []
    for (study, metric), g in movers.dropna(subset=["r2"]).groupby(["study", "metric"], sort=False):
        g = g.sort_values("r2", ascending=False)
        top = g.iloc[0]
        rows.append({"study": study, "metric": metric, "source": top["source"], "r": top["r"], "r2": top["r2"],
                     "slope_per_sd": top["slope_per_sd"], "next": g.iloc[1]["source"] if len(g) > 1 else "",
                     "next_r2": g.iloc[1]["r2"] if len(g) > 1 else np.nan, "n_labs": int(top["n_labs"])})
    order = {m: i for i, m in enumerate(MOVER_METRICS)}
    frame = pd.DataFrame(rows)
    return frame.sort_values(["study", "metric"], key=lambda c: c.map(order) if c.name == "metric" else c,
                             kind="stable").reset_index(drop=True) if len(frame) else frame


def labs_figure(stats: pd.DataFrame):
    """Per study, each direction's bias and SD over the labs (dots, the code's sign: Table II
    prediction minus zone, targeting zone minus target), the Euclidean mean, and the paper's value
    (a cross; its bias also mirrored, the other reading, as a hollow cross)."""
    import matplotlib.pyplot as plt

    paper = paper_statistics().set_index(["study", "metric", "direction"])["paper"]
    items = [(m, d) for m in ("bias", "sd") for d in DIRECTIONS] + [("euclidean_mean", "overall")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for ax, study in zip(axes, ("pose", "targeting")):
        labs = stats[stats["study"] == study]
        for i, (metric, d) in enumerate(items):
            column = f"{metric}_{d}_mm" if metric != "euclidean_mean" else "euclidean_mean_mm"
            values = labs[column].to_numpy(float) if column in labs else np.array([])
            values = values[np.isfinite(values)]
            ax.plot(np.full(values.size, i) + np.linspace(-0.15, 0.15, values.size), values, "o", ms=3,
                    color="tab:blue", alpha=0.6)
            p = float(paper[(study, metric, d)])
            ax.plot(i, p, "x", color="tab:red", ms=9, mew=2)
            if metric == "bias":
                ax.plot(i, -p, "x", color="tab:red", ms=9, mew=1, alpha=0.4)
        ax.set_xticks(range(len(items)), [f"{m.replace('euclidean_mean', 'Euclidean')} {d if d != 'overall' else ''}"
                                          for m, d in items], rotation=40, ha="right")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{'Table II centre' if study == 'pose' else 'targeting'}: {labs['lab'].nunique()} labs")
    axes[0].set_ylabel("mm")
    fig.tight_layout()
    return fig


def labs_text(stats: pd.DataFrame, table: pd.DataFrame, frames: tuple, segmentations: tuple) -> str:
    """The paragraph under the table: the labs, which of the paper's figures lie outside the labs'
    band (in which reading), the signs the code uses, and the frames shared."""
    outside = table[table["inside_band"].eq(False)]
    listed = "; ".join(f"{r.study} {r.metric} {r.direction}" + (f" ({r.reading.replace('_', ' ')})"
                                                                if r.reading != "any" else "")
                       for r in outside.itertuples()) or "none"
    return (f"{stats['lab'].nunique()} labs, all sources on, the same experiments. The paper's figures outside "
            f"the labs' {BAND_PERCENT[0]:g}-{BAND_PERCENT[1]:g} % band: {listed}. Recorded signs: Table II "
            f"{NATIVE_READING['pose']}, targeting {NATIVE_READING['targeting']}; the paper does not say which "
            "difference its biases are, so the bias rows show both readings that treat the two studies alike. "
            f"Frames rendered {frames[0]}, shared {frames[1]}; segmentations made {segmentations[0]}, shared "
            f"{segmentations[1]} (labs share a frame where their transducer and true views are the same).")


@dataclass(frozen=True, eq=False)
class LabsSection:
    """The many labs (:func:`labs_section`): their ``records`` and per-lab ``stats``, the table
    beside the paper (``table``), the bias/scatter ``split``, the ``signs``, the drawn
    ``magnitudes``, the ``movers`` (all and the top ones, ``top_movers``) and the report's ``part``."""

    records: pd.DataFrame
    stats: pd.DataFrame
    table: pd.DataFrame
    split: pd.DataFrame
    signs: pd.DataFrame
    magnitudes: pd.DataFrame
    movers: pd.DataFrame
    top_movers: pd.DataFrame
    part: SectionPart


def labs_section(setup: BudgetSetup, labs: list[LabDraw], budget_records: pd.DataFrame, *,
                 timer: Timer | None = None) -> LabsSection:
    """Notebook 07's many labs beside the paper: labs 1.. run
    (:func:`~histostudy.study.budget.run_labs` on the set-up's study seed and ``params.scheduler``,
    timed as ``"labs"``), lab 0 taken from the budget's "lab" configuration.

    Args:
        setup: the budget's set-up.
        labs: the labs (:func:`prepare_labs`).
        budget_records: :func:`~histostudy.study.budget.run_error_budget`'s rows.
        timer: ``timer(name)`` -> a context manager; None: untimed.

    Returns:
        The :class:`LabsSection`; its part: tables ``labs_vs_paper``, ``bias_scatter``, ``signs``,
        ``movers`` (mm, mm², fractions), figure ``labs``, the labs' counts and a paragraph.

    Raises:
        ValueError: ``setup`` has no ``params`` or ``seeds`` (not made by notebook 07's ``prepare``).
    """
    more = None
    with timer_or_untimed(timer)("labs"):
        if len(labs) > 1:
            more = run_labs(setup, labs[1:], seed=section_seeds(setup).study, indices=range(1, len(labs)),
                            executor=section_params(setup).scheduler or None)
    records = labs_records(budget_records, more)
    stats = lab_statistics(records)
    table = labs_vs_paper(stats, "both")
    split, signs = bias_scatter_split(stats), sign_agreement(stats)
    magnitudes = lab_magnitudes(labs)
    movers = source_movers(stats, magnitudes)
    top = movers_table(movers)
    frames = more.attrs.get("frames", (0, 0)) if more is not None else (0, 0)
    segmentations = more.attrs.get("segmentations", (0, 0)) if more is not None else (0, 0)
    estimates = more.attrs.get("estimates", (0, 0)) if more is not None else (0, 0)
    part = SectionPart(
        tables={"labs_vs_paper": (table, "The paper beside the labs: per study, metric and direction the paper's value "
                                  "(derived: not printed, computed from its MAE, SD and bias), the labs' median and "
                                  "5-95 % band, the paper's percentile among the labs and whether it lies inside the "
                                  "band; biases in both sign readings", {"digits": 2}),
                "bias_scatter": (split, "The squared error's split into bias² and SD² (sums over depth, TB, LR; mm²) "
                                 "and the bias's share: the paper's and the labs' (median, 5-95 % band)",
                                 {"digits": 2}),
                "signs": (signs, "Signs of the biases: the fraction of labs with the paper's sign in Table II, in "
                          "targeting and in both, per reading, and the two studies' biases' correlation over the labs",
                          {"digits": 2}),
                "movers": (top, "Which systematic source moves each figure across the labs: the source whose drawn "
                           "size (mm) explains most of the labs' spread (r², univariate), the change per SD of that "
                           "size, and the runner-up", {"digits": 2})},
        figures={"labs": (labs_figure(stats), "Each lab's bias and SD per direction and Euclidean mean (dots) beside "
                          "the paper's (red cross; its bias mirrored, the other sign reading, faint)")},
        values={"labs_n": int(stats["lab"].nunique()), "labs_frames_made_shared": list(frames),
                "labs_segmentations_made_shared": list(segmentations), "labs_estimates_made_shared": list(estimates)},
        texts=(labs_text(stats, table, frames, segmentations),))
    return LabsSection(records, stats, table, split, signs, magnitudes, movers, top, part)
