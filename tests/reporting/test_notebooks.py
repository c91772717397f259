"""The study notebooks: stored without outputs, each with a tagged parameters cell whose names
the profiles can set, and the whole smoke study through papermill (as `make reproduce` runs it)."""

import json

import nbformat
import pytest
from report_text import report_text

from histostudy.reporting import PROFILE_NAMES, load_profile, run_study
from histostudy.reporting.pipeline import DEFAULT_NOTEBOOK_DIR, discover_notebooks
from histostudy.reporting.section_keys import KEY_FILE

NOTEBOOKS = discover_notebooks(DEFAULT_NOTEBOOK_DIR)


def _parameter_names(nb) -> set[str]:
    (cell,) = [c for c in nb.cells if "parameters" in c.metadata.get("tags", [])]
    names = set()
    for line in cell.source.splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            names.add(line.split("=")[0].strip())
    return names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_is_stored_clean_with_a_parameters_cell(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(not c.outputs and c.execution_count is None for c in code), "commit notebooks without outputs"
    tagged = [c for c in code if "parameters" in c.metadata.get("tags", [])]
    assert len(tagged) == 1, "exactly one cell tagged 'parameters'"
    assert {"profile", "seed", "output_dir"} <= _parameter_names(nb)
    # Bound to the kernel `make env` installs (the project's virtualenv), not to whatever python3 is.
    assert nb.metadata["kernelspec"]["name"] == "histostudy"


@pytest.mark.parametrize("profile", PROFILE_NAMES)
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_profiles_only_set_parameters_the_notebook_declares(path, profile):
    declared = _parameter_names(nbformat.read(path, as_version=4))
    injected = set(load_profile(profile).parameters_for(path.stem)) | {"output_dir"}
    assert injected <= declared, f"{profile} sets undeclared parameters {injected - declared}"


@pytest.mark.slow
@pytest.mark.longest
def test_smoke_study_runs_every_notebook_and_writes_the_report(tmp_path):
    out = tmp_path / "reports"
    # two notebooks at once, as `histostudy reproduce --workers 2` runs them (the same numbers as one)
    run_study("smoke", out, progress=False, log=lambda m: None, workers=2)
    record = json.loads((out / "run.json").read_text())
    assert [n["name"] for n in record["notebooks"]] == [p.stem for p in NOTEBOOKS]
    assert all(n["status"] == "ok" for n in record["notebooks"])
    md = report_text(out)
    for p in NOTEBOOKS:
        res = json.loads((out / p.stem / "results.json").read_text())
        assert res["comparisons"], f"{p.stem} recorded no comparison with the paper"
        assert f"## {res['title']}" in md
        for fig in res["figures"]:
            assert (out / p.stem / fig["path"]).stat().st_size > 1000
    assert (out / "report.html").stat().st_size > 1000
    assert not list(out.rglob("*.tmp*"))
    # the notebooks' sweeps kept their finished tasks in the run's folder (for a resumed section)
    assert list((out / ".sweep-cache").rglob("*.pkl"))

    # run again: every section is kept; a section left without its key (as a stopped run leaves the
    # one it was running) is the only one done again, the cheapest here
    redo = min(record["notebooks"], key=lambda n: n["seconds"])["name"]
    (out / redo / KEY_FILE).unlink()
    stamps = {p.stem: (out / p.stem / "results.json").stat().st_mtime_ns for p in NOTEBOOKS}
    again = run_study("smoke", out, progress=False, log=lambda m: None, workers=2)
    assert [n["name"] for n in again.record["notebooks"] if not n["kept"]] == [redo]
    assert all((out / n / "results.json").stat().st_mtime_ns == t for n, t in stamps.items() if n != redo)
    assert all(n["status"] == "ok" for n in again.record["notebooks"])
