"""SectionWriter and report assembly, without papermill."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from report_text import report_text

from histostudy.core import stage
from histostudy.reporting import SectionWriter, build_report
from histostudy.reporting.report import format_measure, load_section


def test_format_measure():
    assert format_measure(1.3812, 0.5391, "mm") == "1.38 ± 0.54 mm"
    assert format_measure(16, unit="") == "16"
    assert format_measure(float("nan")) == "n/a"
    assert format_measure("310 x 240", unit="px") == "310 x 240 px"


def _section(tmp_path):
    w = SectionWriter(tmp_path / "01_demo", "01_demo", "Demo section", profile="smoke", seed=3,
                      parameters={"a": 1})
    with w.timer("work"):
        w.value("n_points", np.int64(12))
    w.compare("model.radius_mm", "Cap radius", 138.70001, unit="mm")
    w.compare("pose.center_euclidean", "Centre error", (0.41, 0.2), unit="mm")
    w.compare("custom.thing", "Not in paper", 2.0, paper_key="")
    w.table("counts", pd.DataFrame({"class": ["a", "b"], "n": [1, 2]}), "Point counts")
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    w.figure("line", fig, "A line")
    plt.close(fig)
    w.image("shot", np.zeros((8, 8, 3), np.uint8), "A screenshot")
    w.text("Some *markdown*.")
    w.stand_in("porcine projections", "procedural abdomen")
    w.save()
    return w


def test_section_writer_records_everything(tmp_path):
    _section(tmp_path)
    res = load_section(tmp_path / "01_demo")
    assert res["values"]["n_points"] == 12 and res["parameters"] == {"a": 1}
    rows = {c["key"]: c for c in res["comparisons"]}
    assert rows["model.radius_mm"]["paper_text"] == "138.7 mm"
    assert rows["pose.center_euclidean"]["ours_text"] == "0.41 ± 0.20 mm"
    assert rows["pose.center_euclidean"]["paper_text"] == "1.38 ± 0.54 mm"
    assert rows["custom.thing"]["paper_text"] == "not reported"
    assert (tmp_path / "01_demo/tables/counts.csv").read_text().startswith("class,n")
    assert (tmp_path / "01_demo/figures/line.png").read_bytes()[:4] == b"\x89PNG"
    assert res["timings_s"]["work"] >= 0 and "git_commit" in res["provenance"]
    assert not list((tmp_path / "01_demo").rglob("*.tmp*"))


def test_section_writer_records_the_stage_times_since_it_was_made(tmp_path, stage_clock):
    with stage("pose"):
        stage_clock.tick(100.0)  # before the writer: not the section's
    w = SectionWriter(tmp_path / "04_demo", "04_demo", "Demo", profile="smoke", seed=0)
    with stage("pose"):
        stage_clock.tick(2.0, 3.0)
        with stage("render"):
            stage_clock.tick(1.0, 0.5)
    w.table("counts", pd.DataFrame({"n": [1]}))  # writing a table is the report stage
    w.save()
    stages = load_section(tmp_path / "04_demo")["stages"]
    # save's call counts; the time of its own writing cannot be in the file it writes
    assert stages == {"render": {"wall_s": 1.0, "cpu_s": 0.5, "calls": 1},
                      "pose": {"wall_s": 2.0, "cpu_s": 3.0, "calls": 1},
                      "report": {"wall_s": 0.0, "cpu_s": 0.0, "calls": 2}}


def test_unknown_paper_key_is_an_error(tmp_path):
    w = SectionWriter(tmp_path, "x", "x", profile="smoke", seed=0)
    with pytest.raises(KeyError, match="no paper value"):
        w.compare("table1.screws.precisoin", "typo", 1.0)


def test_report_is_assembled_from_results_files(tmp_path):
    _section(tmp_path)
    run = {"profile": "smoke", "seed": 3, "provenance": {"git_commit": "abc", "versions": {"numpy": "2"}},
           "notebooks": [{"name": "01_demo", "status": "ok", "seconds": 1.0, "output_dir": str(tmp_path / "01_demo")},
                         {"name": "02_missing", "status": "pending"}],
           "failure": None}
    md_path, html_path = build_report(tmp_path, run)
    index, page = md_path.read_text(), (tmp_path / "01_demo" / "README.md").read_text()
    assert "## Demo section" in page and "| Cap radius | 138.70 mm | 138.7 mm |" in page
    assert "![A line](figures/line.png)" in page  # the page sits in the section's folder
    assert "porcine projections → procedural abdomen" in page
    assert "| class" in page and page.startswith("[← the report](../REPORT.md)")
    assert "## Demo section" not in index and "- [Demo section](01_demo/README.md#01_demo)" in index
    assert "02_missing" in index and "No results" in index and not (tmp_path / "02_missing").exists()
    html = html_path.read_text()
    assert '<table class="cards">' in html and "data:image/png;base64," in html
    assert "01_demo/figures/line.png" not in html  # embedded, not linked


def test_each_section_names_the_renderer_that_splatted_its_frames(tmp_path):
    for name, device in (("01_cpu", "cpu"), ("02_numpy", "numpy"), ("03_none", None)):
        parameters = {} if device is None else {"splat_device": device}
        SectionWriter(tmp_path / name, name, name, profile="smoke", seed=3, parameters=parameters).save()
    run = {"profile": "smoke", "seed": 3, "notebooks": [{"name": n, "status": "ok", "output_dir": str(tmp_path / n)}
                                                        for n in ("01_cpu", "02_numpy", "03_none")]}
    build_report(tmp_path, run)
    md = report_text(tmp_path)
    first_lines = {n: next(line for line in md.splitlines() if line.startswith(f"*Notebook `{n}`"))
                   for n in ("01_cpu", "02_numpy", "03_none")}
    assert "frames splatted by the compiled kernel (CPU)" in first_lines["01_cpu"]
    assert "frames splatted by the numpy reference" in first_lines["02_numpy"]
    assert "splatted" not in first_lines["03_none"]  # a section that renders nothing names no renderer


def test_report_names_a_failure(tmp_path):
    run = {"profile": "smoke", "seed": 1, "notebooks": [{"name": "01_x", "status": "failed"}],
           "failure": {"notebook": "01_x", "cell_index": 4, "error": "ValueError: boom",
                       "executed_notebook": "e.ipynb"}}
    md, _ = build_report(tmp_path, run)
    assert "Run failed" in md.read_text() and "ValueError: boom" in md.read_text()


def test_report_lists_every_paper_result_and_where_it_is_reproduced(tmp_path):
    from histostudy.reporting import PAPER
    from histostudy.reporting.twins import results_coverage

    w = SectionWriter(tmp_path / "04_pose", "04", "Pose", profile="smoke", seed=3)
    w.compare("table2.center_mae.overall", "Centre MAE", 0.6, unit="mm")
    w.compare("pose.centre_cbct", "Centre error vs CBCT", 0.64, unit="mm", paper_key="pose.center_euclidean")
    w.compare("pose.speed", "Speed", 0.7, unit="s", paper_key="")
    w.save()
    coverage = results_coverage({"04_pose": load_section(tmp_path / "04_pose")})
    by_key = {c["key"]: c for c in coverage}
    assert by_key["table2.center_mae.overall"]["sections"] == ["04_pose"]
    assert by_key["pose.center_euclidean"]["sections"] == ["04_pose"]  # matched through paper_key
    assert by_key["targeting.euclidean"]["sections"] == []
    assert "model.radius_mm" not in by_key  # §II set-up values are not results
    expected = {k for k, v in PAPER.items() if "§III" in v.where or "Table" in v.where or "abstract" in v.where}
    assert set(by_key) == expected and "seg.anova_F" in expected
    run = {"profile": "smoke", "seed": 3, "provenance": {}, "failure": None,
           "notebooks": [{"name": "04_pose", "status": "ok", "seconds": 1.0, "output_dir": str(tmp_path / "04_pose")}]}
    md = build_report(tmp_path, run)[0].read_text()
    assert md.count("The paper's results and their reproduced twins") == 2  # its heading, and the link in the headline
    assert md.count("## The paper's results and their reproduced twins") == 1
    assert f"**2 of {len(expected)}** have a twin in this run" in md
    page = "04_pose/README.md#04_pose"
    # below the paper's for the known reason (reporting/expected.py); no error budget in this run to link
    assert ("| centre MAE, overall (Table II) | 1.4 ± 0.5 mm | 0.60 mm | -0.80 mm | **better than the paper** "
            "(1.6 SD below): no lab error in synthetic frames: the C-arm's calibration and sag, the CBCT "
            f"registration, the robot and the phantom's motion are left out | [04_pose]({page}) | "
            "`table2.center_mae.overall` |") in md
    assert ("| targeting error, Euclidean (§III, abstract 1.4 ± 0.5) | 1.64 ± 0.34 mm | — | — | "
            "not in this run: notebook 05 was not run |  | `targeting.euclidean` |") in md


def test_first_screen_comes_first_and_every_section_is_in_the_contents(tmp_path):
    _section(tmp_path)
    run = {"profile": "smoke", "seed": 3, "provenance": {"versions": {"numpy": "2"}}, "failure": None,
           "notebooks": [{"name": "01_demo", "status": "ok", "seconds": 1.0, "output_dir": str(tmp_path / "01_demo")},
                         {"name": "06_your_data", "status": "pending"}]}
    md = build_report(tmp_path, run)[0].read_text()
    order = ["> [!WARNING]", "| Paper result | Paper | This run | Difference | Status |", "## Contents",
             "## This run", "## 06_your_data", "## The paper's results", "## Software"]
    assert all(marker in md for marker in order), [marker for marker in order if marker not in md]
    positions = [md.index(marker) for marker in order]
    assert positions == sorted(positions)
    assert "- [Demo section](01_demo/README.md#01_demo)" in md and "- [06_your_data](#06_your_data)" in md
    # links made before the report had pages land on the index, beside the link to the page
    assert '<a id="01_demo"></a><a id="01_demo-stand-ins"></a>' in md
    page = (tmp_path / "01_demo" / "README.md").read_text()
    assert '<a id="01_demo-stand-ins"></a>' in page and "## Demo section" in page
    # a gap in the direction this study expects reads so in the section's own table too
    assert "| Centre error | 0.41 ± 0.20 mm | 1.38 ± 0.54 mm | -0.97 mm, better than the paper (1.8 SD below) |" in page
    # the whole report, every section on one page, is report.html's
    assert "Demo section" in (tmp_path / "report.html").read_text()


def test_tables_with_pipes_in_their_names_stay_tables(tmp_path):
    w = SectionWriter(tmp_path / "04_pose", "04_pose", "Pose", profile="smoke", seed=3)
    w.table("variants", pd.DataFrame({"mode": ["paper"], "centre |depth|": [0.5]}), "Centre |error|")
    w.save()
    text = (tmp_path / "04_pose/tables/variants.md").read_text()
    assert text.splitlines()[0] == "| mode | centre \\|depth\\| |"
    run = {"profile": "smoke", "seed": 3, "provenance": {}, "failure": None,
           "notebooks": [{"name": "04_pose", "status": "ok", "seconds": 1.0, "output_dir": str(tmp_path / "04_pose")}]}
    html = build_report(tmp_path, run)[1].read_text()
    assert ">centre |depth|</th>" in html and "<strong>Centre |error|</strong>" in html


def test_a_long_table_is_cut_on_its_page_and_whole_in_the_csv_and_report_html(tmp_path):
    from histostudy.reporting.pages import MAX_TABLE_ROWS

    w = SectionWriter(tmp_path / "03_long", "03_long", "Long", profile="smoke", seed=3)
    w.table("frames", pd.DataFrame({"frame": range(MAX_TABLE_ROWS + 5), "error": 0.5}), "Every frame")
    w.table("short", pd.DataFrame({"frame": range(MAX_TABLE_ROWS)}), "Forty frames")
    w.save()
    run = {"profile": "smoke", "seed": 3, "provenance": {}, "failure": None,
           "notebooks": [{"name": "03_long", "status": "ok", "seconds": 1.0, "output_dir": str(tmp_path / "03_long")}]}
    _, html = build_report(tmp_path, run)
    page = (tmp_path / "03_long" / "README.md").read_text()
    assert f"*25 more rows of {MAX_TABLE_ROWS + 5}: the whole table is [frames.csv](tables/frames.csv)" in page
    assert "| 19 |" in page and "| 20 |" not in page.split("Forty frames")[0]  # the first 20 rows of 45
    assert page.split("Forty frames")[1].count("\n|") == MAX_TABLE_ROWS + 2  # 40 rows: whole
    assert f'text-align: right;">{MAX_TABLE_ROWS + 4}</td>' in html.read_text()  # the last row, in report.html
    assert len(pd.read_csv(tmp_path / "03_long" / "tables" / "frames.csv")) == MAX_TABLE_ROWS + 5
