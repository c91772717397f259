"""A finished run published into the repository: what is copied and what is not, refusals before
anything is written, the staleness check against the current profile, the README's headline, and the
repository's own published runs checked against today's profiles."""

import json
import os
import re
from pathlib import Path

import pytest

from histostudy.cli import main
from histostudy.core.io import process_umask
from histostudy.core.provenance import REPO_ROOT
from histostudy.reporting import load_profile, publish_run, replace_readme_headline
from histostudy.reporting.pipeline import DEFAULT_NOTEBOOK_DIR, discover_notebooks
from histostudy.reporting.publish import README_HEADLINE_BEGIN, README_HEADLINE_END, readme_headline, stale_parameters

PUBLISHED = REPO_ROOT / "docs" / "results"


def _finished_run(folder, names=("01_transducer_and_projections", "02_segmentation"), profile="smoke"):
    """A reproduce folder as the pipeline leaves it: sections, executed notebooks, a cache file and
    run.json with the profile's parameters and absolute paths."""
    prof = load_profile(profile)
    for name in names:
        folder.section(name, compare=[folder.paper_comparison("seg.global_accuracy")], image=True)
        (folder.root / name / "frames.npz").write_bytes(b"\0" * 64)
    (folder.root / "notebooks").mkdir(exist_ok=True)
    for i, name in enumerate(names):  # papermill's record names the machine's paths
        # the second section is kept from a run in another folder, whose paths its notebook holds
        ran_in = folder.root if i == 0 else Path("/elsewhere/reports")
        executed = {"cells": [{"cell_type": "code", "source": f'output_dir = "{ran_in / name}"\n',
                               "outputs": [{"output_type": "stream", "text": f"{ran_in / name}/results.json"}]}],
                    "metadata": {"papermill": {"input_path": "/home/me/histostudy/notebooks/x.ipynb",
                                               "output_path": str(ran_in / "notebooks" / ".x.tmp.ipynb"),
                                               "parameters": {"output_dir": str(ran_in / name)}}}}
        (folder.root / "notebooks" / f"{name}.ipynb").write_text(json.dumps(executed))
        (folder.root / name / "section_key.json").write_text(json.dumps(
            {"key": "0" * 64, "machine": {"cpu_model": "Test CPU", "executable": "/home/me/.venv/bin/python"}}))
    run = folder.run(profile, parameters={n: prof.parameters_for(n) | {"output_dir": str(folder.root / n)}
                                          for n in names})
    run["seed"] = prof.seed
    run["provenance"]["machine"] = {"cpu_model": "Test CPU", "cpus": 2, "executable": "/home/me/.venv/bin/python",
                                    "isa_flags": {"avx2": True}, "isa_restriction": {}}
    run["profile_source"] = f"/home/me/histostudy/histostudy/reporting/profiles/{profile}.toml"
    results = folder.root / names[0] / "results.json"  # a shipped file, named by the checkout's path
    results.write_text(json.dumps({**json.loads(results.read_text()),
                                   "weights": "/home/me/histostudy/data/models/unet_standard.safetensors"}))
    (folder.root / "run.json").write_text(json.dumps(run))
    return run


def test_publish_copies_results_tables_figures_and_executed_notebooks_not_caches(folder, tmp_path):
    _finished_run(folder)
    report = publish_run(folder.root, tmp_path / "pub", allow_partial=True)
    pub = tmp_path / "pub"
    assert report == pub / "REPORT.md" and (pub / "report.html").is_file()
    assert (pub / "02_segmentation" / "results.json").is_file()
    assert list((pub / "02_segmentation").rglob("*.png")), "figures are published"
    assert not list(pub.rglob("*.npz"))
    # the executed notebooks, for the documentation site, without the machine's paths
    assert sorted(p.name for p in (pub / "notebooks").iterdir()) == [
        "01_transducer_and_projections.ipynb", "02_segmentation.ipynb"]
    text = (pub / "notebooks" / "02_segmentation.ipynb").read_text()
    assert str(folder.root) not in text and "/home/me" not in text and "/elsewhere" not in text
    executed = json.loads(text)
    assert executed["cells"][0]["source"] == 'output_dir = "02_segmentation"\n'
    assert executed["metadata"]["papermill"]["input_path"] == "notebooks/02_segmentation.ipynb"
    run = json.loads((pub / "run.json").read_text())
    assert all(not os.path.isabs(n.get("output_dir", "")) for n in run["notebooks"])
    assert "executable" not in run["provenance"]["machine"]
    assert run["profile_source"] == "histostudy/reporting/profiles/smoke.toml"
    results = json.loads((pub / "01_transducer_and_projections" / "results.json").read_text())
    assert results["weights"] == "data/models/unet_standard.safetensors"
    for path in pub.rglob("*"):  # no published file names a path of the machine that made the run
        if path.suffix in (".json", ".md", ".csv", ".ipynb"):
            text = path.read_text()
            assert "/home/me" not in text and "/elsewhere" not in text and str(folder.root) not in text, path
    # the notebooks that did not run are named, in order, as not run
    names = [n["name"] for n in run["notebooks"]]
    assert names == sorted(names) and len(names) == len(discover_notebooks(DEFAULT_NOTEBOOK_DIR))
    assert {n["status"] for n in run["notebooks"][2:]} == {"not run"}
    md = report.read_text()
    assert "No results: status not run" in md and "Test CPU, 2 cores; ISA avx2" in md
    modes = {p.stat().st_mode & 0o777 for p in pub.rglob("*") if p.is_file()}
    assert modes == {0o666 & ~process_umask()}


def test_publish_refuses_unfinished_or_partial_runs_before_writing(folder, tmp_path):
    run = _finished_run(folder)
    with pytest.raises(ValueError, match="did not run notebooks 03_orientation.*allow_partial"):
        publish_run(folder.root, tmp_path / "pub")
    run["notebooks"][1]["status"] = "interrupted"
    (folder.root / "run.json").write_text(json.dumps(run))
    with pytest.raises(ValueError, match="notebooks 02_segmentation did not finish"):
        publish_run(folder.root, tmp_path / "pub", allow_partial=True)
    with pytest.raises(ValueError, match="holds no readable run.json"):
        publish_run(tmp_path / "nowhere", tmp_path / "pub")
    assert not (tmp_path / "pub").exists() and not list(tmp_path.glob(".pub*"))


def test_publish_replaces_the_folder_whole(folder, tmp_path):
    _finished_run(folder)
    pub = tmp_path / "pub"
    (pub / "99_old").mkdir(parents=True)
    publish_run(folder.root, pub, allow_partial=True)
    assert not (pub / "99_old").exists() and (pub / "01_transducer_and_projections").is_dir()


def test_stale_parameters_names_each_difference_from_the_profile(folder, tmp_path):
    run = _finished_run(folder)
    assert stale_parameters(folder.root) == []
    run["seed"] = 7
    run["notebooks"][1]["parameters"]["n_eval_images"] = 999
    del run["notebooks"][0]["parameters"]["background"]
    (folder.root / "run.json").write_text(json.dumps(run))
    found = stale_parameters(folder.root)
    smoke = load_profile("smoke")
    assert f"seed: published 7, profile {smoke.seed}" in found
    assert any(line.startswith("02_segmentation.n_eval_images: published 999") for line in found)
    assert any(line.startswith("01_transducer_and_projections.background: profile smoke has") for line in found)
    assert len(found) == 3


def test_the_readme_headline_links_into_the_published_report(folder, tmp_path):
    _finished_run(folder)
    publish_run(folder.root, tmp_path / "pub", allow_partial=True)
    block = readme_headline(tmp_path / "pub", "docs/results/smoke/REPORT.md")
    assert "](docs/results/smoke/REPORT.md#" in block and "](#" not in block
    # a section's result links to its page beside the published REPORT.md
    assert re.search(r"\]\(docs/results/smoke/\d\d_\w+/README\.md#\d\d_\w+\)", block)
    assert "| Paper result |" in block
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{README_HEADLINE_BEGIN}\nold\n{README_HEADLINE_END}\n\nrest\n")
    replace_readme_headline(readme, tmp_path / "pub", "docs/results/smoke/REPORT.md")
    text = readme.read_text()
    assert "old" not in text and block in text and text.endswith("\n\nrest\n")
    readme.write_text("no markers")
    with pytest.raises(ValueError, match="must hold <!-- published-headline:begin -->"):
        replace_readme_headline(readme, tmp_path / "pub", "x")


def test_cli_publish_writes_the_folder_and_the_readme(folder, tmp_path, capsys):
    _finished_run(folder)
    readme = tmp_path / "README.md"
    readme.write_text(f"{README_HEADLINE_BEGIN}\n{README_HEADLINE_END}\n")
    assert main(["publish", str(folder.root), "--to", str(tmp_path / "docs" / "pub")]) == 2
    assert "did not run notebooks" in capsys.readouterr().err
    assert main(["publish", str(folder.root), "--to", str(tmp_path / "docs" / "pub"), "--readme", str(readme),
                 "--partial"]) == 0
    assert "](docs/pub/REPORT.md#" in readme.read_text()


@pytest.mark.parametrize("published", sorted(p for p in PUBLISHED.glob("*") if (p / "run.json").is_file()),
                         ids=lambda p: p.name)
def test_the_repository_s_published_runs_match_today_s_profiles(published):
    stale = stale_parameters(published)
    assert not stale, (f"{published.relative_to(REPO_ROOT)} was made with other parameters than profile "
                       f"{published.name} has now; run it again and publish (histostudy publish): " + "; ".join(stale))


@pytest.mark.parametrize("published", sorted(p for p in PUBLISHED.glob("*") if (p / "run.json").is_file()),
                         ids=lambda p: p.name)
def test_the_readme_shows_the_published_headline(published):
    block = readme_headline(published, f"{published.relative_to(REPO_ROOT).as_posix()}/REPORT.md")
    assert block in (REPO_ROOT / "README.md").read_text(), (
        f"README.md's headline differs from {published.relative_to(REPO_ROOT)}: "
        "histostudy publish ... --readme README.md")


def test_a_published_long_table_keeps_its_csv_and_its_page_shows_it_cut(folder, tmp_path):
    import pandas as pd

    from histostudy.reporting import build_report
    from histostudy.reporting.pages import MAX_TABLE_ROWS

    long = pd.DataFrame({"frame": range(3 * MAX_TABLE_ROWS), "error_mm": 0.25})
    folder.section("02_segmentation", compare=[folder.paper_comparison("seg.global_accuracy")],
                   tables=[("per_frame", long, "Every frame"), ("short", long.head(5), "Five frames")])
    prof = load_profile("smoke")
    run = folder.run("smoke", parameters={"02_segmentation": prof.parameters_for("02_segmentation")})
    (folder.root / "run.json").write_text(json.dumps(run))
    publish_run(folder.root, tmp_path / "pub", allow_partial=True)
    tables = tmp_path / "pub" / "02_segmentation" / "tables"
    assert sorted(p.name for p in tables.iterdir()) == ["per_frame.csv", "short.csv", "short.md"]
    page = (tmp_path / "pub" / "02_segmentation" / "README.md").read_text()
    assert f"more rows of {3 * MAX_TABLE_ROWS}: the whole table is [per_frame.csv](tables/per_frame.csv)" in page
    assert all(len(p.read_text().splitlines()) <= 400 for p in (tmp_path / "pub").rglob("*.md"))
    # rebuilt from the published folder, the long table comes from its CSV: cut on the page, whole in the html
    build_report(tmp_path / "pub")
    assert (tmp_path / "pub" / "02_segmentation" / "README.md").read_text().count("\n| ") == page.count("\n| ")
    assert f'text-align: right;">{3 * MAX_TABLE_ROWS - 1}</td>' in (tmp_path / "pub" / "report.html").read_text()


@pytest.mark.parametrize("published", sorted(p for p in PUBLISHED.glob("*") if (p / "run.json").is_file()),
                         ids=lambda p: p.name)
def test_a_published_report_reads_in_pages(published):
    index = (published / "REPORT.md").read_text(encoding="utf-8")
    assert len(index.splitlines()) <= 300, "REPORT.md is an index: headline, contents, this run, twins"
    long = {p.relative_to(published).as_posix(): n for p in published.rglob("*.md")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 400}
    assert not long, f"published Markdown files over 400 lines: {long}"
    run = json.loads((published / "run.json").read_text())
    assert all((published / n["name"] / "README.md").is_file() for n in run["notebooks"] if n["status"] == "ok")
