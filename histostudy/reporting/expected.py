"""Differences from the paper this synthetic study has for a known cause (:func:`known_cause`): a
sentence the number's section shows and its status links to; for a pose or targeting error below
the paper's (no lab error in synthetic frames), the status "better than the paper" (docs/report.md,
"How the status is decided")."""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

from histostudy.core import is_finite_real

from .agreement import DIFFERS, FAR_OFF, Agreement, judge
from .paper import PAPER

__all__ = ["BETTER", "BUDGET_SECTION", "KNOWN_CAUSES", "KnownCause", "as_sentence", "known_cause",
           "section_causes"]

#: The status the report gives a difference this study expects, in its favour (an error below the paper's).
BETTER = "better than the paper"

#: The section that adds the lab's error sources back (its anchor).
BUDGET_SECTION = "07_error_budget"

_DIRECTIONS = ("lower", "higher", "nearer zero", "any")


@dataclass(frozen=True)
class KnownCause:
    """A group of the paper's results that differ here for one known cause.

    Args:
        slug: the cause's anchor in a section's page (``<section>-why-<slug>``).
        title: a few words naming the cause: the status's link text.
        patterns: ``fnmatch`` patterns of the paper keys it covers.
        direction: the differences it explains: ``"lower"`` or ``"higher"`` (the reproduced value
            below or above the paper's), ``"nearer zero"`` (a bias smaller in magnitude), ``"any"``.
        reason: the sentence the report shows (Markdown).
        better: whether a difference it explains reads :data:`BETTER` instead of differs / far off
            (an error below the paper's).
        excluded_rows: ``fnmatch`` patterns of comparison keys (``SectionWriter.compare``'s ``key``)
            it never covers: rows where the cause does not hold (the error budget's labs, which add
            the lab's errors).
    """

    slug: str
    title: str
    patterns: tuple[str, ...]
    direction: str
    reason: str
    better: bool = False
    excluded_rows: tuple[str, ...] = ()

    def __post_init__(self):
        if self.direction not in _DIRECTIONS:
            raise ValueError(f"direction={self.direction!r}: expected one of {_DIRECTIONS}")

    def covers(self, key: str, row_key: str | None = None) -> bool:
        """Whether the paper key ``key`` is one of this cause's, for the comparison ``row_key``."""
        if row_key is not None and any(fnmatch.fnmatchcase(row_key, p) for p in self.excluded_rows):
            return False
        return any(fnmatch.fnmatchcase(key, p) for p in self.patterns)

    def explains(self, ours, paper_mean, agreement: Agreement) -> bool:
        """Whether a difference (``agreement``, reproduced ``ours`` against ``paper_mean``) lies in
        this cause's direction."""
        if self.direction == "any":
            return True
        if self.direction == "nearer zero":
            return is_finite_real(ours) and is_finite_real(paper_mean) and abs(float(ours)) < abs(float(paper_mean))
        if agreement.difference is None:
            return False
        return agreement.difference < 0 if self.direction == "lower" else agreement.difference > 0


_NO_LAB_ERROR = ("no lab error in synthetic frames: the C-arm's calibration and sag, the CBCT registration, the "
                 "robot and the phantom's motion are left out")
_FRAMES = ("The frames are synthetic: a procedural background without the anatomy, table and instruments of "
           "the paper's porcine and phantom frames, Poisson noise, and labels that are the model's exact "
           "projection rather than drawn by hand. The large classes, background and transducer, are easier to "
           "tell apart here, and the global figures follow them.")
_UNET = ("The shipped U-Net is much narrower than the paper's (64–1,024 channels) and was trained on a CPU, not "
         "a GPU, for a fraction of the paper's training; its architecture and training are among the stand-ins "
         "below. The thin classes, the screws and the gaps, fall short first.")
_BOUNDARIES = ("The boundary classes are labelled here by projecting the model's boundary bands, whose widths "
               "are assumed (docs/imaging.md), by one rule in training and test; the paper's were drawn by hand, "
               "and its network recalled less than half of each. The two are different targets: the boundary "
               "figures differ from the paper's in either direction.")
_SPREAD = ("The ANOVA's F and Tukey's interval measure how far the classes' precisions spread; they follow the "
           "per-class precisions of Table I, and differ from the paper's as those do.")
_ANOVA_COUNT = ("The within-class degrees of freedom count every frame once per class (frames × classes − "
                "classes); the paper's count is smaller, in a way it does not describe (frames without the class "
                "left out, perhaps).")
_VGG = ("The shipped VGG19 is a fraction of the paper's width and was trained on a CPU for a fraction of the "
        "paper's 400,000 GPU iterations; its architecture and training are among the stand-ins below. Near "
        "elevation 0° the azimuth is ill-defined (a small tilt turns it far); the per-frame angles show where "
        "the errors lie.")

#: The comparisons that add the lab's errors to the synthetic frames' (notebook 07's labs).
_LAB_ERROR_ROWS = ("budget.lab.*",)

#: The known causes, checked in order: a key takes the first that covers it in its direction.
KNOWN_CAUSES = (
    KnownCause("anova-count", "how the ANOVA counts", ("seg.anova_df_within",), "any", _ANOVA_COUNT),
    KnownCause("class-spread", "the classes' spread", ("seg.anova_F", "seg.tukey_*"), "any", _SPREAD),
    KnownCause("boundaries", "the boundary labels", ("table1.outer_boundary.*", "table1.inner_boundary.*"), "any",
               _BOUNDARIES),
    KnownCause("network", "a small U-Net trained on a CPU", ("table1.*", "seg.*"), "lower", _UNET),
    KnownCause("frames", "synthetic frames", ("table1.*", "seg.*"), "higher", _FRAMES),
    KnownCause("network", "a small VGG19 trained on a CPU", ("angles.*",), "any", _VGG),
    KnownCause("no-lab-error", "no lab error", ("table2.*_mae.*", "pose.center_euclidean", "pose.center_mae.*",
                                                "pose.radius_mae", "pose.margin_distance", "targeting.euclidean",
                                                "targeting.mae.*", "targeting.radius_mae"),
               "lower", _NO_LAB_ERROR, better=True, excluded_rows=_LAB_ERROR_ROWS),
    KnownCause("no-lab-error", "no lab error", ("table2.center_bias.*", "pose.center_bias.*", "targeting.bias.*"),
               "nearer zero", _NO_LAB_ERROR, better=True, excluded_rows=_LAB_ERROR_ROWS),
)


def known_cause(key: str, ours, paper_mean, agreement: Agreement | None, *,
                row_key: str | None = None) -> KnownCause | None:
    """The known cause of a reproduced number's difference from the paper's.

    Args:
        key: the paper's key (``"targeting.euclidean"``).
        ours: the reproduced value.
        paper_mean: the paper's value.
        agreement: the number's :class:`~.agreement.Agreement`.
        row_key: the comparison's own key (``"budget.lab.targeting.euclidean"``), which a cause
            may exclude; None: any comparison.

    Returns:
        The first of :data:`KNOWN_CAUSES` that covers ``key`` in the difference's direction, when
        the number differs (or is far off); None otherwise (it agrees, is not judged, or no cause
        covers it).
    """
    if agreement is None or agreement.status not in (DIFFERS, FAR_OFF):
        return None
    return next((cause for cause in KNOWN_CAUSES
                 if cause.covers(key, row_key) and cause.explains(ours, paper_mean, agreement)), None)


def section_causes(comparisons: list[dict]) -> list[tuple[KnownCause, list[str]]]:
    """The known causes of a section's differences from the paper, each once (causes of one slug
    together), in :data:`KNOWN_CAUSES`' order, with the labels of the comparisons each explains.

    Args:
        comparisons: the section's comparison rows (``SectionWriter.compare``'s).

    Returns:
        ``[(cause, labels), ...]``; empty when no comparison differs for a known cause.
    """
    found: dict[str, tuple[KnownCause, list[str]]] = {}
    for row in comparisons:
        key = row.get("paper_key") or ""
        value = PAPER.get(key)
        if value is None:
            continue
        cause = known_cause(key, row.get("ours"), value.mean, judge(row, value, twin=PAPER.get(value.twin)),
                            row_key=row.get("key"))
        if cause is not None:
            labels = found.setdefault(cause.slug, (cause, []))[1]
            if row["label"] not in labels:
                labels.append(row["label"])
    order = {cause.slug: i for i, cause in reversed(list(enumerate(KNOWN_CAUSES)))}
    return sorted(found.values(), key=lambda item: order[item[0].slug])


def as_sentence(text: str) -> str:
    """``text`` with a capital first letter and a closing full stop (a cause's reason on its own line)."""
    text = text.strip()
    return f"{text[:1].upper()}{text[1:]}" + ("" if text.endswith((".", "!", "?")) else ".")
