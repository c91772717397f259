"""Every paper result and its reproduced twin: found through its key or its Table II twin, the
primary comparison chosen, and a reason for each missing one."""

from histostudy.reporting import PAPER
from histostudy.reporting.agreement import AGREES
from histostudy.reporting.report import load_section
from histostudy.reporting.twins import RESULT_KEYS, results_coverage


def _sections(folder):
    return {name: load_section(folder.root / name) for name in folder.names}


def test_results_are_the_77_numbers_of_section_iii_the_tables_and_the_abstract():
    assert len(RESULT_KEYS) == 77
    assert "model.radius_mm" not in RESULT_KEYS and "seg.n_images" not in RESULT_KEYS
    assert all(PAPER[k].label for k in RESULT_KEYS)
    # the §III pose paragraph's numbers repeat Table II's
    twins = {k: PAPER[k].twin for k in RESULT_KEYS if PAPER[k].twin}
    assert twins["pose.margin_distance"] == "table2.margin_mae.overall"
    assert len(twins) == 9 and all(t in RESULT_KEYS for t in twins.values())


def test_every_paper_number_is_twinned_when_every_notebook_records_its_own(folder):
    # what notebooks 02-05 record: every result under its own key, except the §III numbers that
    # repeat Table II (notebook 04 records Table II only)
    by_notebook = {"02_seg": ("table1.", "seg."), "03_angles": ("angles.",), "04_pose": ("table2.", "pose."),
                   "05_targeting": ("targeting.",)}
    for name, prefixes in by_notebook.items():
        keys = [k for k in RESULT_KEYS
                if k.startswith(prefixes) and not (PAPER[k].twin and k != "pose.center_euclidean")]
        compare = [folder.paper_comparison(k) for k in keys]
        compare = [dict(c, ours="2e-08") if c["key"] == "seg.anova_p" else c for c in compare]  # p < 1e-5
        folder.section(name, compare=compare, stand_ins=[("lab", "synthetic")])
    coverage = results_coverage(_sections(folder), folder.run())
    assert [row["key"] for row in coverage] == list(RESULT_KEYS)
    missing = [row["key"] for row in coverage if row["comparison"] is None]
    assert missing == []
    by_key = {row["key"]: row for row in coverage}
    margin = by_key["pose.margin_distance"]
    assert margin["via"] == "table2.margin_mae.overall" and margin["section"] == "04_pose"
    assert margin["comparison"]["ours"] == 1.0  # Table II's reproduced value, judged against §III's 1.04 ± 0.22
    assert margin["agreement"].status == AGREES
    assert all(row["agreement"].status == AGREES for row in coverage)  # intervals overlap, bounds hold


def test_the_primary_comparison_is_the_one_under_the_paper_key(folder):
    folder.section("05_targeting", compare=[
        dict(key="targeting.corrected.euclidean", label="corrected", ours=0.4, unit="mm",
             paper_key="targeting.euclidean"),
        dict(key="targeting.euclidean", label="plain", ours=1.7, unit="mm")])
    row = {r["key"]: r for r in results_coverage(_sections(folder))}["targeting.euclidean"]
    assert row["comparison"]["label"] == "plain" and row["sections"] == ["05_targeting"]
    assert row["agreement"].difference_text() == "+0.06 mm"


def test_a_missing_tukey_interval_says_the_screws_were_not_predicted(folder):
    folder.section("02_seg", compare=[dict(key="table1.screws.precision", label="screws: precision",
                                           ours=(float("nan"), float("nan")), unit="%"),
                                      dict(key="seg.anova_F", label="F", ours=4.0)])
    row = {r["key"]: r for r in results_coverage(_sections(folder), folder.run())}["seg.tukey_screws_vs_background_ci"]
    assert row["comparison"] is None and row["agreement"] is None
    assert row["reason"].startswith("not computed in [02_seg](#02_seg): Tukey's test takes a class")
    assert row["reason"].endswith("this run's screws precision: n/a")


def test_reasons_name_the_notebook_that_did_not_run_or_finish(folder):
    folder.section("02_seg", compare=[folder.paper_comparison("seg.global_accuracy")])
    run = folder.run(extra=["04_pose"], statuses={"04_pose": "failed"})
    by_key = {r["key"]: r for r in results_coverage(_sections(folder), run)}
    assert by_key["targeting.euclidean"]["reason"] == "not in this run: notebook 05 was not run"
    assert by_key["table2.center_mae.overall"]["reason"] == \
        "not in this run: notebook `04_pose` did not finish (failed)"
    assert by_key["seg.weighted_iou"]["reason"] == "[02_seg](#02_seg) records no comparison for it"
