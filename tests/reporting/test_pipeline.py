"""The papermill pipeline on tiny notebooks: order, parameters, results, failures, CLI errors."""

import json

import nbformat
import pytest

from histostudy.cli import main
from histostudy.reporting import NotebookFailed, discover_notebooks, run_study, select_notebooks

PARAMS = 'profile = "smoke"\nseed = 0\noutput_dir = "."\nfactor = 1\n'


def _notebook(path, body):
    nb = nbformat.v4.new_notebook()
    params = nbformat.v4.new_code_cell(PARAMS)
    params.metadata["tags"] = ["parameters"]
    nb.cells = [nbformat.v4.new_markdown_cell("# toy"), params] + [nbformat.v4.new_code_cell(b) for b in body]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.write(nb, path)


WRITE = ("from histostudy.reporting.report import SectionWriter\n"
         "w = SectionWriter(output_dir, '{name}', 'Toy {name}', profile=profile, seed=seed)\n"
         "w.value('product', seed * factor)\n"
         "w.compare('render.n_splats', 'Splats', 16 * factor)\n"
         "w.save()")


@pytest.fixture
def toy_notebooks(tmp_path):
    folder = tmp_path / "notebooks"
    folder.mkdir()
    _notebook(folder / "01_first.ipynb", [WRITE.format(name="01_first")])
    _notebook(folder / "02_second.ipynb", [WRITE.format(name="02_second")])
    (folder / "README.md").write_text("not a notebook")
    return folder


def test_discover_and_select(toy_notebooks):
    nbs = discover_notebooks(toy_notebooks)
    assert [p.stem for p in nbs] == ["01_first", "02_second"]
    assert [p.stem for p in select_notebooks(nbs, ["second", "01"])] == ["01_first", "02_second"]
    with pytest.raises(ValueError, match="'third'.*01_first, 02_second"):
        select_notebooks(nbs, ["third"])


@pytest.mark.slow
def test_run_writes_sections_executed_notebooks_and_report(toy_notebooks, tmp_path):
    out = tmp_path / "reports"
    run = run_study("smoke", out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    for name in ("01_first", "02_second"):
        res = json.loads((out / name / "results.json").read_text())
        assert res["profile"] == "smoke" and res["seed"] == run.record["seed"]
        assert (out / "notebooks" / f"{name}.ipynb").is_file()
    md = run.report_md.read_text()
    assert "## Toy 01_first" in md and "## Toy 02_second" in md and "| Splats | 16 | 16 |" in md
    assert run.report_html.is_file()
    record = json.loads((out / "run.json").read_text())
    assert [n["status"] for n in record["notebooks"]] == ["ok", "ok"]
    assert not list(out.rglob("*.tmp*"))


@pytest.mark.slow
def test_failing_notebook_names_notebook_and_cell_and_keeps_copy(toy_notebooks, tmp_path):
    _notebook(toy_notebooks / "01_first.ipynb", ["x = 1", "raise ValueError('boom in cell three')"])
    out = tmp_path / "reports"
    with pytest.raises(NotebookFailed) as err:
        run_study("smoke", out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    exc = err.value
    assert exc.notebook == "01_first" and "boom in cell three" in exc.error
    assert str(exc.cell_index).startswith("3 ")  # markdown, parameters, x = 1, raise
    assert exc.executed_notebook.is_file()
    assert not (out / "02_second").exists()  # the run stopped
    assert "Run failed" in (out / "REPORT.md").read_text()
    assert not list(out.rglob("*.tmp*"))


@pytest.mark.slow
def test_cli_exit_codes(toy_notebooks, tmp_path, capsys):
    _notebook(toy_notebooks / "02_second.ipynb", ["1 / 0"])
    code = main(["reproduce", "--profile", "smoke", "--output", str(tmp_path / "r"), "--notebooks",
                 str(toy_notebooks), "--only", "02", "--no-progress"])
    assert code == 1
    assert "02_second failed at cell 2" in capsys.readouterr().err
    assert main(["reproduce", "--notebooks", str(toy_notebooks), "--only", "nope", "--output", str(tmp_path / "r")]) == 2
    with pytest.raises(SystemExit) as exit_info:
        main(["reproduce", "--profile", "no-such-profile"])
    assert exit_info.value.code == 2
    assert "no-such-profile" in capsys.readouterr().err
