"""The report's first screen: the profile's banner, the headline of the paper's key results and
the contents."""

from histostudy.reporting import PAPER
from histostudy.reporting.headline import HEADLINE_KEYS, contents_markdown, headline_markdown, profile_banner
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
        "⚠ **far off** (33 SD above); why: [03 stand-ins](#03_angles-stand-ins) |")
    assert rows["angles.elevation.mae"].endswith("| +0.74 deg | **agrees** (0.3 SD) |")
    assert rows["targeting.euclidean"].endswith("| — | — | not in this run: notebook 05 was not run |")
    for key in HEADLINE_KEYS:
        assert PAPER[key].format() in rows[key]


def test_contents_links_every_entry():
    lines = contents_markdown([("01 · Model | views", "01_model"), ("Software", "software")])
    assert lines[0] == '<a id="contents"></a>'
    assert "- [01 · Model \\| views](#01_model)" in lines and "- [Software](#software)" in lines
