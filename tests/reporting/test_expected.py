"""A difference this study has for a known reason (no lab error in synthetic frames) reads "better
than the paper" with its reason; the same number on the paper's wrong side, or any other result,
keeps its status."""

import pytest

from histostudy.reporting import PAPER
from histostudy.reporting.agreement import AGREES, FAR_OFF, judge
from histostudy.reporting.expected import expected_reason
from histostudy.reporting.twins import status_markdown


def _agreement(key, ours):
    return judge({"ours": ours, "unit": PAPER[key].unit, "ours_text": f"{ours:.2f}"}, PAPER[key],
                 twin=PAPER.get(PAPER[key].twin))


@pytest.mark.parametrize("key, ours, expected", [
    ("targeting.euclidean", 0.61, True),     # 3 SD below 1.64 ± 0.34: far off, in the expected direction
    ("targeting.euclidean", 2.90, False),    # as far above: a real problem
    ("table2.center_mae.overall", 0.57, True),
    ("table2.center_bias.lr", -0.1, True),   # a bias nearer zero than the paper's -0.8 ± 0.6
    ("table2.center_bias.lr", -1.6, False),  # a larger one
    ("targeting.euclidean", 1.60, False),    # agrees: nothing to explain
    ("table1.screws.precision", 99.0, False),  # no known reason covers Table I
])
def test_a_known_reason_covers_only_its_keys_and_direction(key, ours, expected):
    agreement = _agreement(key, ours)
    reason = expected_reason(key, ours, PAPER[key].mean, agreement)
    assert (reason is not None) == expected
    if expected:
        assert "no lab error in synthetic frames" in reason and agreement.status != AGREES


def test_the_status_cell_says_better_with_the_reason_and_links_the_budget():
    key = "targeting.euclidean"
    agreement = _agreement(key, 0.61)
    assert agreement.status == FAR_OFF
    row = {"key": key, "agreement": agreement, "comparison": {"ours": 0.61}, "section": "05_targeting",
           "stand_ins": [{"lab": "x", "synthetic": "y"}], "budget_in_run": True}
    cell = status_markdown(row)
    assert cell.startswith("**better than the paper** (3.0 SD below): no lab error") and "⚠" not in cell
    assert cell.endswith("[the error budget adds them](#07_error_budget)")
    assert "error budget" not in status_markdown({**row, "budget_in_run": False})
    worse = {**row, "agreement": _agreement(key, 2.9), "comparison": {"ours": 2.9}}
    assert status_markdown(worse).startswith("⚠ **far off**")
