"""The report's first screen: the profile's banner, the headline of the paper's key results, the
contents and the run's facts with its time by stage."""

from histostudy.reporting import PAPER
from histostudy.reporting.headline import (
    HEADLINE_KEYS,
    contents_markdown,
    headline_markdown,
    profile_banner,
    run_facts,
    stage_table,
)
from histostudy.reporting.report import load_section
from histostudy.reporting.twins import results_coverage


def test_smoke_banner_says_it_is_not_a_reproduction_with_the_run_sizes(folder):
    run = folder.run("smoke", extra=["02_seg", "04_pose"],
                     parameters={"02_seg": {"n_eval_images": 4}, "04_pose": {"n_experiments": 1}})
    lines = profile_banner(run, "CI and a first look")
    assert lines[0] == "> [!WARNING]" and lines[-1] == ""
    text = lines[1]
    assert "exercises the pipeline; it is not a reproduction" in text
    assert "In this run, evaluation frames: 4 (the paper: 310); pose experiments: 1 (the paper: 10)." in text
    assert "CI and a first look." in text and "targeting" not in text


def test_standard_paper_and_custom_banners(folder):
    assert profile_banner(folder.run("standard"))[0] == "> [!NOTE]"
    assert "a reproduction at the paper's study sizes" in profile_banner(folder.run("standard"))[1]
    assert "hyper-parameters" in profile_banner(folder.run("paper"))[1]
    custom = profile_banner(folder.run("my_lab"), "Our <own> sizes")[1]
    assert "Profile my_lab: a custom run" in custom and "Our &lt;own> sizes." in custom


def test_headline_sets_each_key_result_beside_the_paper_with_difference_and_status(folder):
    folder.section("03_angles", stand_ins=[("VGG19 on GPU", "a CPU VGG19")], compare=[
        dict(key="angles.azimuth.mae", label="azimuth MAE", ours=(24.63, 31.29), unit="deg"),
        dict(key="angles.elevation.mae", label="elevation MAE", ours=(3.08, 3.31), unit="deg")])
    coverage = results_coverage({"03_angles": load_section(folder.root / "03_angles")}, folder.run())
    table = headline_markdown(coverage)[0].splitlines()
    assert table[0] == "| Paper result | Paper | This run | Difference | Status |"
    assert len(table) == 2 + len(HEADLINE_KEYS)
    rows = {key: line for key, line in zip(HEADLINE_KEYS, table[2:])}
    assert rows["angles.azimuth.mae"] == (
        "| [Azimuth MAE (§III)](#03_angles) | 1.06 ± 0.71 deg | 24.63 ± 31.29 deg | +23.57 deg | "
        "⚠ **far off** (33 SD above); why: [a small VGG19 trained on a CPU](#03_angles-why-network), "
        "[03 stand-ins](#03_angles-stand-ins) |")
    assert rows["angles.elevation.mae"].endswith("| +0.74 deg | **agrees** (0.3 SD) |")
    assert rows["targeting.euclidean"].endswith("| — | — | not in this run: notebook 05 was not run |")
    for key in HEADLINE_KEYS:
        assert PAPER[key].format() in rows[key]


def test_contents_links_every_entry():
    lines = contents_markdown([("01 · Model | views", "01_model"), ("Software", "software")])
    assert lines[0] == '<a id="contents"></a>'
    assert "- [01 · Model \\| views](#01_model)" in lines and "- [Software](#software)" in lines


def test_this_run_shows_each_section_s_time_by_stage():
    run = {"profile": "standard", "seed": 1, "notebooks": [
        {"name": "01_model", "status": "ok", "seconds": 180.0, "cpu_seconds": 240.0,
         "stages": {"render": {"wall_s": 60.0, "cpu_s": 90.0, "calls": 2},
                    "report": {"wall_s": 6.0, "cpu_s": 6.0, "calls": 9}},
         "other": {"wall_s": 114.0, "cpu_s": 144.0}},
        # kept from an earlier run: its recorded stages; notebooks run at once: no CPU time of its own
        {"name": "04_pose", "status": "ok", "kept": True, "seconds": 600.0, "cpu_seconds": None,
         "stages": {"render": {"wall_s": 120.0, "cpu_s": 150.0, "calls": 40},
                    "pose": {"wall_s": 420.0, "cpu_s": 800.0, "calls": 20}},
         "other": {"wall_s": 60.0, "cpu_s": None}},
        # a section of a version that recorded no stages
        {"name": "05_targeting", "status": "ok", "seconds": 30.0, "cpu_seconds": 30.0},
        {"name": "06_lab", "status": "failed"}]}
    header, rows, unit = stage_table(run)
    assert unit == "min" and header == ["Section", "render", "pose", "report", "other", "total"]
    assert rows == [
        ["01_model", "1.0 / 1.5", "—", "0.1 / 0.1", "1.9 / 2.4", "3.0 / 4.0"],
        ["04_pose (kept)", "2.0 / 2.5", "7.0 / 13.3", "—", "1.0 / n/a", "10.0 / n/a"],
        ["05_targeting", "n/a", "n/a", "n/a", "n/a", "0.5 / 0.5"],
        ["all sections", "n/a", "n/a", "n/a", "n/a", "13.5 / n/a"]]
    lines = run_facts(run)
    assert not any("Sweeps ran on" in line for line in lines)  # a run that did not record it
    assert "- Sweeps ran on: `local:2` (docs/sweeps.md; the numbers do not depend on it)" in run_facts(
        {**run, "sweeps": "local:2"})
    caption = next(i for i, line in enumerate(lines) if line.startswith("Time by stage, wall / CPU in min"))
    table = lines[caption + 2].splitlines()
    assert table[:3] == ["| Section | render | pose | report | other | total |", "|:---|---:|---:|---:|---:|---:|",
                         "| 01_model | 1.0 / 1.5 | — | 0.1 / 0.1 | 1.9 / 2.4 | 3.0 / 4.0 |"]

    # all known, all short: seconds, and the sums
    run["notebooks"] = run["notebooks"][:1]
    run["notebooks"][0].update(seconds=100.0, cpu_seconds=None, other={"wall_s": 34.0, "cpu_s": None})
    header, rows, unit = stage_table(run)
    assert unit == "s" and rows[-1] == ["all sections", "60.0 / 90.0", "6.0 / 6.0", "34.0 / n/a", "100.0 / n/a"]
    # no section recorded stages (a run of an earlier version): no table
    assert stage_table({"notebooks": [{"name": "01_model", "seconds": 5.0}]}) is None
    assert not any("Time by stage" in line for line in run_facts({"notebooks": [{"name": "01", "seconds": 5.0}]}))


def test_this_run_adds_a_resumed_section_s_stopped_attempts_to_the_time():
    run = {"profile": "standard", "seed": 1, "wall_seconds": 700.0, "notebooks": [
        {"name": "06_lab", "status": "ok", "kept": True, "seconds": 300.0},
        {"name": "07_budget", "status": "ok", "seconds": 600.0,
         "earlier_attempts": {"count": 2, "seconds": 3000.0, "cpu_seconds": None}}]}
    lines = run_facts(run)
    assert ("- Wall time of the sections: 65.0 min, of which 5.0 min in earlier runs whose sections were kept; "
            "50.0 min of the total in stopped attempts of resumed sections; this run: 11.7 min") in lines
    assert ("- Notebooks: `06_lab` (ok, kept, 300 s), `07_budget` (ok, 600 s, after 2 stopped attempts of 3000 s)"
            in lines)
