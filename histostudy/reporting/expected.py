"""Differences from the paper this synthetic study has for a known reason (:func:`expected_reason`):
a pose or targeting error below the paper's, where the lab's error sources that the paper's numbers
carry are left out of the synthetic frames (docs/report.md, "How the status is decided")."""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

from .agreement import DIFFERS, FAR_OFF, Agreement

__all__ = ["BETTER", "BUDGET_SECTION", "EXPECTED_DIFFERENCES", "ExpectedDifference", "expected_reason"]

#: The status the report gives a difference this study expects, in its favour (an error below the paper's).
BETTER = "better than the paper"

#: The section that adds the lab's error sources back (its anchor).
BUDGET_SECTION = "07_error_budget"

NO_LAB_ERROR = ("no lab error in synthetic frames: the C-arm's calibration and sag, the CBCT registration, the "
                "robot and the phantom's motion are left out")


@dataclass(frozen=True)
class ExpectedDifference:
    """A group of paper results that this study is expected to beat, and why.

    Args:
        patterns: ``fnmatch`` patterns of the paper keys it covers.
        better: ``"lower"`` (an error) or ``"nearer zero"`` (a bias).
        reason: the sentence the report shows.
    """

    patterns: tuple[str, ...]
    better: str
    reason: str

    def covers(self, key: str) -> bool:
        return any(fnmatch.fnmatchcase(key, p) for p in self.patterns)


#: The known reasons, checked in order.
EXPECTED_DIFFERENCES = (
    ExpectedDifference(("table2.*_mae.*", "pose.center_euclidean", "pose.center_mae.*", "pose.radius_mae",
                        "pose.margin_distance", "targeting.euclidean", "targeting.mae.*", "targeting.radius_mae"),
                       "lower", NO_LAB_ERROR),
    ExpectedDifference(("table2.center_bias.*", "pose.center_bias.*", "targeting.bias.*"), "nearer zero",
                       NO_LAB_ERROR),
)


def expected_reason(key: str, ours, paper_mean, agreement: Agreement | None) -> str | None:
    """Why a reproduced number that differs from the paper's is better than it, where the reason is known.

    Args:
        key: the paper's key (``"targeting.euclidean"``).
        ours: the reproduced value.
        paper_mean: the paper's value.
        agreement: the number's :class:`~.agreement.Agreement`.

    Returns:
        The reason, when the number differs (or is far off) in the direction the reason predicts;
        None otherwise (it agrees, differs the other way, or no reason covers its key).
    """
    if agreement is None or agreement.status not in (DIFFERS, FAR_OFF) or agreement.difference is None:
        return None
    for expected in EXPECTED_DIFFERENCES:
        if not expected.covers(key):
            continue
        if expected.better == "lower":
            better = agreement.difference < 0
        else:
            better = abs(float(ours)) < abs(float(paper_mean))
        return expected.reason if better else None
    return None
