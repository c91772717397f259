"""A difference this study has for a known cause: a pose or targeting error below the paper's (no
lab error in synthetic frames) reads "better than the paper" with its reason; a learned stage's gap
links to the section's sentence on its cause, then to the stand-ins; the same number on the other
side of the paper, or a result no cause covers, keeps its status and plain link."""

import json

import pytest

from histostudy.reporting import PAPER, build_report
from histostudy.reporting.agreement import AGREES, FAR_OFF, judge
from histostudy.reporting.expected import KNOWN_CAUSES, KnownCause, known_cause, section_causes
from histostudy.reporting.twins import status_markdown, why_anchor


def _agreement(key, ours):
    return judge({"ours": ours, "unit": PAPER[key].unit, "ours_text": f"{ours:.2f}"}, PAPER[key],
                 twin=PAPER.get(PAPER[key].twin))


def _cause(key, ours):
    return known_cause(key, ours, PAPER[key].mean, _agreement(key, ours))


@pytest.mark.parametrize("key, ours, slug, better", [
    ("targeting.euclidean", 0.61, "no-lab-error", True),   # 3 SD below 1.64 ± 0.34, the expected direction
    ("targeting.euclidean", 2.90, None, None),             # as far above: a real problem, no cause
    ("table2.center_mae.overall", 0.57, "no-lab-error", True),
    ("table2.center_bias.lr", -0.1, "no-lab-error", True),  # a bias nearer zero than the paper's -0.8 ± 0.6
    ("table2.center_bias.lr", -1.6, None, None),           # a larger one
    ("targeting.euclidean", 1.60, None, None),             # agrees: nothing to explain
    ("table1.screws.precision", 40.0, "network", False),   # below the paper: the small network
    ("table1.screws.precision", 99.9, "frames", False),    # above it: the easier synthetic frames
    ("table1.outer_boundary.recall", 88.8, "boundaries", False),  # either way: different labels
    ("table1.outer_boundary.precision", 60.0, "boundaries", False),
    ("angles.azimuth.mae", 17.4, "network", False),
    ("seg.anova_df_within", 1854, "anova-count", False),
    ("pose.n_studies", 99, None, None),                    # no cause covers the study's counts
])
def test_a_known_cause_covers_only_its_keys_and_direction(key, ours, slug, better):
    cause = _cause(key, ours)
    assert (cause.slug if cause else None) == slug
    if cause is not None:
        assert cause.better == better and _agreement(key, ours).status != AGREES
    if better:
        assert "no lab error in synthetic frames" in cause.reason


def test_a_cause_checks_its_direction():
    with pytest.raises(ValueError, match="direction='up'"):
        KnownCause("x", "x", ("a.*",), "up", "because")
    # a slug is one sentence on a section's page: causes that share it say the same, or cover
    # groups of keys no section mixes
    for i, a in enumerate(KNOWN_CAUSES):
        for b in KNOWN_CAUSES[i + 1:]:
            if a.slug == b.slug and (a.title, a.reason) != (b.title, b.reason):
                assert not {p.split(".")[0] for p in a.patterns} & {p.split(".")[0] for p in b.patterns}


def test_no_lab_error_is_no_cause_where_the_lab_s_errors_are_added():
    key = "targeting.bias.lr"
    agreement = _agreement(key, -0.52)  # nearer zero than the paper's -1.01
    assert known_cause(key, -0.52, PAPER[key].mean, agreement, row_key="budget.baseline.targeting.bias.lr").better
    assert known_cause(key, -0.52, PAPER[key].mean, agreement, row_key="budget.lab.targeting.bias.lr") is None


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
    assert status_markdown(worse) == ("⚠ **far off** (3.7 SD above); why: "
                                      "[05 stand-ins](#05_targeting-stand-ins)")


def test_the_status_cell_links_the_cause_then_the_stand_ins():
    key = "table1.screws.recall"
    row = {"key": key, "agreement": _agreement(key, 40.0), "comparison": {"ours": 40.0}, "section": "02_seg",
           "stand_ins": [{"lab": "x", "synthetic": "y"}], "budget_in_run": False}
    assert status_markdown(row) == ("**differs** (2.8 SD below); why: [a small U-Net trained on a CPU]"
                                    "(#02_seg-why-network), [02 stand-ins](#02_seg-stand-ins)")
    alone = status_markdown({**row, "stand_ins": []})
    assert alone.endswith("why: [a small U-Net trained on a CPU](#02_seg-why-network)")


def test_a_section_page_states_each_cause_once_before_its_stand_ins(folder):
    low = PAPER["table1.screws.precision"]
    folder.section("02_seg", stand_ins=[("a GPU U-Net", "a CPU U-Net")], compare=[
        dict(key="table1.screws.precision", label="screws precision", ours=(low.mean - 3 * low.sd, 1.0), unit="%"),
        dict(key="table1.screws.recall", label="screws recall", ours=(10.0, 1.0), unit="%"),
        dict(key="table1.background.precision", label="background precision", ours=(99.9, 0.1), unit="%"),
        folder.paper_comparison("table1.transducer.precision")])
    causes = section_causes(json.loads((folder.root / "02_seg" / "results.json").read_text())["comparisons"])
    assert [(c.slug, labels) for c, labels in causes] == [
        ("network", ["screws precision", "screws recall"]), ("frames", ["background precision"])]
    build_report(folder.root, folder.run())
    page = (folder.root / "02_seg" / "README.md").read_text()
    why, stand_ins = page.index(f'<a id="{why_anchor("02_seg", "network")}"></a>'), page.index("02_seg-stand-ins")
    assert why < page.index(f'<a id="{why_anchor("02_seg", "frames")}"></a>') < stand_ins
    assert "**a small U-Net trained on a CPU** (screws precision, screws recall): The shipped U-Net" in page
    assert "transducer precision" not in page[why:stand_ins]  # it agrees: no cause to give
    assert page.count("-why-network") == 1
    index = (folder.root / "REPORT.md").read_text()
    assert "[a small U-Net trained on a CPU](02_seg/README.md#02_seg-why-network)" in index

