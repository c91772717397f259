"""The papermill pipeline on tiny notebooks: order, parameters, results, failures, CLI errors, and the
profile refused before anything runs or is written."""

import json

import nbformat
import pytest
from report_text import report_text

from histostudy.cli import main
from histostudy.reporting import NotebookFailed, run_study
from histostudy.reporting.pipeline import discover_notebooks, section_stages, select_notebooks

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


@pytest.fixture
def toy_profile(tmp_path):
    # The shipped profiles' tables name the study notebooks, which the toy folder lacks.
    path = tmp_path / "toy.toml"
    path.write_text('name = "toy"\nseed = 3\n[common]\nfactor = 1\n[notebooks.02_second]\nfactor = 2\n')
    return path


def test_discover_and_select(toy_notebooks):
    nbs = discover_notebooks(toy_notebooks)
    assert [p.stem for p in nbs] == ["01_first", "02_second"]
    assert [p.stem for p in select_notebooks(nbs, ["second", "01"])] == ["01_first", "02_second"]
    with pytest.raises(ValueError, match="'third'.*01_first, 02_second"):
        select_notebooks(nbs, ["third"])


def test_a_section_s_stages_and_the_time_outside_them_go_into_its_run_entry(tmp_path):
    section = tmp_path / "04_pose"
    section.mkdir()
    stages = {"render": {"wall_s": 30.0, "cpu_s": 50.0, "calls": 4},
              "pose": {"wall_s": 60.0, "cpu_s": 90.0, "calls": 2}}
    (section / "results.json").write_text(json.dumps({"section": "04_pose", "stages": stages}))
    assert section_stages(section, 100.0, 200.0) == {"stages": stages, "other": {"wall_s": 10.0, "cpu_s": 60.0}}
    assert section_stages(section, 100.0, None)["other"] == {"wall_s": 10.0, "cpu_s": None}  # ran beside others
    # a sweep's workers' stage times add up to more than the section's wall time: nothing is left outside
    assert section_stages(section, 80.0, 120.0)["other"] == {"wall_s": 0.0, "cpu_s": 0.0}
    (section / "results.json").write_text(json.dumps({"section": "04_pose"}))  # an earlier version's
    assert section_stages(section, 100.0, 200.0) == {}
    assert section_stages(tmp_path / "missing", 100.0, 200.0) == {}


@pytest.mark.slow
def test_run_writes_sections_executed_notebooks_and_report(toy_notebooks, toy_profile, tmp_path):
    out = tmp_path / "reports"
    run = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    for name in ("01_first", "02_second"):
        res = json.loads((out / name / "results.json").read_text())
        assert res["profile"] == "toy" and res["seed"] == run.record["seed"] == 3
        assert (out / "notebooks" / f"{name}.ipynb").is_file()
    md = report_text(out)
    assert "## Toy 01_first" in md and "## Toy 02_second" in md and "| Splats | 16 | 16 |" in md
    assert "| Splats | 32 | 16 |" in md  # 02_second's own table wins over [common]
    assert run.report_html.is_file()
    record = json.loads((out / "run.json").read_text())
    assert [n["status"] for n in record["notebooks"]] == ["ok", "ok"]
    for entry in record["notebooks"]:  # the section's stages (its save's call) and the time outside them
        assert entry["stages"]["report"]["calls"] == 1 and 0 <= entry["other"]["wall_s"] <= entry["seconds"]
    assert not list(out.rglob("*.tmp*"))


@pytest.mark.slow
def test_failing_notebook_names_notebook_and_cell_and_keeps_copy(toy_notebooks, toy_profile, tmp_path):
    _notebook(toy_notebooks / "01_first.ipynb", ["x = 1", "raise ValueError('boom in cell three')"])
    out = tmp_path / "reports"
    with pytest.raises(NotebookFailed) as err:
        run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    exc = err.value
    assert exc.notebook == "01_first" and "boom in cell three" in exc.error
    assert str(exc.cell_index).startswith("3 ")  # markdown, parameters, x = 1, raise
    assert exc.executed_notebook.is_file()
    assert not (out / "02_second").exists()  # the run stopped
    assert "Run failed" in (out / "REPORT.md").read_text()
    assert not list(out.rglob("*.tmp*"))


@pytest.mark.slow
def test_cli_exit_codes(toy_notebooks, toy_profile, tmp_path, capsys):
    _notebook(toy_notebooks / "02_second.ipynb", ["1 / 0"])
    code = main(["reproduce", "--profile", str(toy_profile), "--output", str(tmp_path / "r"), "--notebooks",
                 str(toy_notebooks), "--only", "02", "--no-progress"])
    assert code == 1
    assert "02_second failed at cell 2" in capsys.readouterr().err
    assert main(["reproduce", "--profile", str(toy_profile), "--notebooks", str(toy_notebooks), "--only", "nope",
                 "--output", str(tmp_path / "r")]) == 2
    with pytest.raises(SystemExit) as exit_info:
        main(["reproduce", "--profile", "no-such-profile"])
    assert exit_info.value.code == 2
    assert "no-such-profile" in capsys.readouterr().err


@pytest.mark.parametrize("text, expected", [
    ('seed = 3\n[common]\nfactr = 2\n', r"'factr' in \[common\].*did you mean 'factor'\?"),
    ('seed = 3\n[notebooks.02_secnd]\nfactor = 2\n', r"\[notebooks.02_secnd\].*did you mean \[notebooks.02_second\]\?"),
    ('seed = 3\n[notebooks.01_first]\nfactors = 2\n', r"'factors' in \[notebooks.01_first\].*did you mean 'factor'\?"),
])
def test_run_refuses_a_bad_profile_before_writing_anything(toy_notebooks, tmp_path, text, expected):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "reports"
    logged = []
    with pytest.raises(ValueError, match=expected) as err:
        run_study(path, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    assert str(path) in str(err.value)
    assert not out.exists() and not logged
    # also when the table is for a notebook that --only leaves out
    with pytest.raises(ValueError, match=expected):
        run_study(path, out, only=["02" if "01_first" in text else "01"], notebooks_dir=toy_notebooks,
                  progress=False, log=logged.append)
    assert not out.exists() and not logged


def test_shipped_profile_is_refused_for_a_folder_without_its_notebooks(toy_notebooks, tmp_path):
    out = tmp_path / "reports"
    out.mkdir()
    with pytest.raises(ValueError,
                       match=r"(?s)smoke.toml.*\[notebooks.01_transducer_and_projections\] names no notebook"):
        run_study("smoke", out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    assert not list(out.iterdir())


def test_cli_reports_a_bad_profile_with_exit_status_2(toy_notebooks, tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text('seed = 3\n[common]\nfactr = 2\n')
    out = tmp_path / "r"
    assert main(["reproduce", "--profile", str(path), "--notebooks", str(toy_notebooks), "--output", str(out),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "histostudy reproduce:" in err and "did you mean 'factor'?" in err and not out.exists()
    path.write_text("seed = 1.7\n")
    with pytest.raises(SystemExit) as exit_info:
        main(["reproduce", "--profile", str(path), "--notebooks", str(toy_notebooks), "--output", str(out)])
    assert exit_info.value.code == 2
    assert "'seed' must be a non-negative integer, got 1.7 (float)" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_a_signal_stops_the_kernel_leaves_no_temporary_file_and_marks_the_section(tmp_path, toy_profile,
                                                                                 signal_name):
    import os
    import signal
    import subprocess
    import sys
    import time

    folder = tmp_path / "notebooks"
    folder.mkdir()
    marker = tmp_path / "kernel.pid"
    # an earlier, complete run left results in the section: an interrupted run must not show them
    _notebook(folder / "01_first.ipynb", [WRITE.format(name="01_first")])
    _notebook(folder / "02_second.ipynb", [
        "import os, time\nfrom pathlib import Path\n"
        "from histostudy.core import atomic_path\n"
        f"Path({str(marker)!r}).write_text(str(os.getpid()))\n"
        "with atomic_path(Path(output_dir) / 'big.csv') as tmp:\n    tmp.write_text('half')\n    time.sleep(120)\n"])
    out = tmp_path / "out"
    (out / "02_second").mkdir(parents=True)
    (out / "02_second" / "results.json").write_text('{"section": "02_second", "stale": true}')
    cmd = [sys.executable, "-m", "histostudy.cli", "reproduce", "--profile", str(toy_profile), "--notebooks",
           str(folder), "--output", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not marker.exists():
        assert proc.poll() is None and time.monotonic() < deadline, "the second notebook never started"
        time.sleep(0.1)
    kernel_pid = int(marker.read_text())
    time.sleep(1.0)  # inside the half-written file's block
    proc.send_signal(getattr(signal, signal_name))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + getattr(signal, signal_name), err
    assert f"interrupted by {signal_name}" in err
    time.sleep(0.5)
    with pytest.raises(ProcessLookupError):  # the kernel is gone
        os.kill(kernel_pid, 0)
    assert [p for p in out.rglob(".*tmp*")] == []  # no temporary file left, in the section or elsewhere
    assert not (out / "02_second" / "big.csv").exists()
    run = json.loads((out / "run.json").read_text())
    assert [n["status"] for n in run["notebooks"]] == ["ok", "interrupted"]
    # the interrupted section carries no content key: the next run does it again, keeping 01
    assert (out / "01_first" / "section_key.json").is_file() and not (out / "02_second" / "section_key.json").exists()
    # the stopped attempt's time is kept, for the run that finishes the section to add up
    attempts = json.loads((out / "02_second" / "section_attempts.json").read_text())["attempts"]
    assert [a["status"] for a in attempts] == ["interrupted"] and attempts[0]["seconds"] >= 1.0
    report = (out / "REPORT.md").read_text()
    assert f"interrupted by {signal_name}" in report and "stale" not in report


@pytest.mark.slow
def test_notebooks_run_at_once_give_the_same_sections_in_order_and_a_failure_stops_new_ones(tmp_path, toy_profile):
    import time

    folder = tmp_path / "notebooks"
    folder.mkdir()
    # 01 takes a second: 02 (on the other worker) runs beside it and finishes first
    _notebook(folder / "01_first.ipynb", ["import time\ntime.sleep(1.0)", WRITE.format(name="01_first")])
    _notebook(folder / "02_second.ipynb", [WRITE.format(name="02_second")])
    serial = run_study(toy_profile, tmp_path / "serial", notebooks_dir=folder, progress=False, log=lambda m: None)
    logged = []
    t0 = time.perf_counter()
    both = run_study(toy_profile, tmp_path / "both", notebooks_dir=folder, progress=False, log=logged.append,
                     workers=2)
    assert [n["name"] for n in both.record["notebooks"]] == [n["name"] for n in serial.record["notebooks"]] \
        == ["01_first", "02_second"]
    assert [n["status"] for n in both.record["notebooks"]] == [n["status"] for n in serial.record["notebooks"]] \
        == ["ok", "ok"]
    assert logged.index("      02_second done in " + f"{both.record['notebooks'][1]['seconds']:.1f} s") < \
        logged.index("      01_first done in " + f"{both.record['notebooks'][0]['seconds']:.1f} s")
    assert time.perf_counter() - t0 < sum(n["seconds"] for n in both.record["notebooks"])  # they overlapped
    for name in ("01_first", "02_second"):
        a = json.loads((tmp_path / "serial" / name / "results.json").read_text())
        b = json.loads((tmp_path / "both" / name / "results.json").read_text())
        assert (a["values"], a["comparisons"]) == (b["values"], b["comparisons"])

    # 01 fails at once: 02, already running beside it, finishes; 03 never starts
    _notebook(folder / "01_first.ipynb", ["raise RuntimeError('broken on purpose')"])
    _notebook(folder / "02_second.ipynb", ["import time\ntime.sleep(1.0)", WRITE.format(name="02_second")])
    _notebook(folder / "03_third.ipynb", [WRITE.format(name="03_third")])
    with pytest.raises(NotebookFailed, match="01_first failed at cell 2.*broken on purpose"):
        run_study(toy_profile, tmp_path / "failed", notebooks_dir=folder, progress=False, log=lambda m: None,
                  workers=2)
    record = json.loads((tmp_path / "failed" / "run.json").read_text())
    assert [n["status"] for n in record["notebooks"]] == ["failed", "ok", "pending"]
    assert record["failure"]["notebook"] == "01_first"


def test_the_kernels_sweeps_run_on_the_cores_left_unless_the_environment_says_where(tmp_path, toy_profile,
                                                                                    monkeypatch):
    import os

    folder = tmp_path / "notebooks"
    folder.mkdir()
    _notebook(folder / "01_first.ipynb", [WRITE.format(name="01_first").replace(
        "w.save()", "import os\nw.value('scheduler', os.environ.get('HISTOSTUDY_SCHEDULER'))\nw.save()")])
    _notebook(folder / "02_second.ipynb", [WRITE.format(name="02_second")])
    monkeypatch.delenv("HISTOSTUDY_SCHEDULER", raising=False)

    def seen(out):
        return json.loads((out / "01_first" / "results.json").read_text())["values"]["scheduler"]

    run = run_study(toy_profile, tmp_path / "three", notebooks_dir=folder, progress=False, log=lambda m: None,
                    sweep_workers=3)
    assert seen(tmp_path / "three") == run.record["sweeps"] == "local:3"
    assert "HISTOSTUDY_SCHEDULER" not in os.environ  # the run's setting left with it
    one = run_study(toy_profile, tmp_path / "one", notebooks_dir=folder, progress=False, log=lambda m: None,
                    sweep_workers=1, force=True)
    assert seen(tmp_path / "one") == one.record["sweeps"] == "sequential"
    monkeypatch.setenv("HISTOSTUDY_SCHEDULER", "tcp://scheduler.lab:8786")  # a cluster chosen by the user wins
    logged = []
    cluster = run_study(toy_profile, tmp_path / "cluster", notebooks_dir=folder, progress=False, log=logged.append,
                        sweep_workers=3)
    assert seen(tmp_path / "cluster") == cluster.record["sweeps"] == "tcp://scheduler.lab:8786"
    assert "sweeps: tcp://scheduler.lab:8786 ($HISTOSTUDY_SCHEDULER)" in logged
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match=f"sweep_workers must be None or a positive integer .*got {bad!r}"):
            run_study(toy_profile, tmp_path / "bad", notebooks_dir=folder, sweep_workers=bad)


@pytest.mark.parametrize("workers", [0, -1, 1.5, True, "2"])
def test_workers_must_be_a_positive_integer(toy_notebooks, toy_profile, tmp_path, workers):
    with pytest.raises(ValueError, match=f"workers must be a positive integer .*got {workers!r}"):
        run_study(toy_profile, tmp_path / "out", notebooks_dir=toy_notebooks, workers=workers)
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_rerun_keeps_finished_sections_and_redoes_what_changed(toy_notebooks, toy_profile, tmp_path):
    from histostudy.reporting.section_keys import KEY_FILE

    out = tmp_path / "reports"
    run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    stamps = {n: (out / n / "results.json").stat().st_mtime_ns for n in ("01_first", "02_second")}
    logged = []
    again = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    assert [n["kept"] for n in again.record["notebooks"]] == [True, True]
    assert all((out / n / "results.json").stat().st_mtime_ns == t for n, t in stamps.items())
    assert sum("unchanged since" in line for line in logged) == 2
    assert again.record["notebooks"][0]["seconds"] == json.loads((out / "01_first" / KEY_FILE).read_text())["seconds"]
    kept_stages = json.loads((out / "01_first" / "results.json").read_text())["stages"]
    assert again.record["notebooks"][0]["stages"] == kept_stages and "other" in again.record["notebooks"][0]
    assert "kept from an earlier run" in report_text(out)

    # a parameter of 02 changes: 02 runs, 01 is kept; the log says why and how long the last run took
    toy_profile.write_text(toy_profile.read_text().replace("factor = 2", "factor = 5"))
    logged.clear()
    changed = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    assert [n["kept"] for n in changed.record["notebooks"]] == [True, False]
    assert any("02_second" in line and "runs: parameters" in line for line in logged), logged
    assert json.loads((out / "02_second" / "results.json").read_text())["comparisons"][0]["ours"] == 80

    # the notebook changes: it runs again; with force every notebook runs
    _notebook(toy_notebooks / "01_first.ipynb", ["x = 1", WRITE.format(name="01_first")])
    logged.clear()
    run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    assert any("01_first" in line and "runs: notebook" in line for line in logged), logged
    forced = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None, force=True)
    assert [n["kept"] for n in forced.record["notebooks"]] == [False, False]


@pytest.mark.slow
def test_a_run_stopped_by_a_failure_resumes_without_redoing_the_finished_section(toy_notebooks, toy_profile,
                                                                                tmp_path):
    from histostudy.reporting.section_keys import KEY_FILE

    good = (toy_notebooks / "02_second.ipynb").read_bytes()
    _notebook(toy_notebooks / "02_second.ipynb", ["raise RuntimeError('the machine went away')"])
    out = tmp_path / "reports"
    with pytest.raises(NotebookFailed):
        run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    assert (out / "01_first" / KEY_FILE).is_file() and not (out / "02_second" / KEY_FILE).exists()
    stamp = (out / "01_first" / "results.json").stat().st_mtime_ns
    (toy_notebooks / "02_second.ipynb").write_bytes(good)
    logged = []
    resumed = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    assert [(n["status"], n["kept"]) for n in resumed.record["notebooks"]] == [("ok", True), ("ok", False)]
    assert (out / "01_first" / "results.json").stat().st_mtime_ns == stamp
    # the estimate of 02 comes from nowhere (it never finished); the finished 01 is not counted as time left
    assert any("02_second" in line and "no earlier run with these parameters" in line for line in logged), logged
    # the failed attempt ran another notebook (another key): it is not this section's time
    assert "earlier_attempts" not in resumed.record["notebooks"][1]
    assert not (out / "02_second" / "section_attempts.json").exists()


@pytest.mark.slow
def test_a_resumed_section_adds_up_its_stopped_attempts(toy_notebooks, toy_profile, tmp_path):
    from histostudy.reporting.section_keys import ATTEMPTS_FILE, KEY_FILE

    # the same notebook (the same key) fails until the machine has what it needs, as a stopped run resumes
    ready = tmp_path / "ready"
    _notebook(toy_notebooks / "02_second.ipynb", [
        f"import time\nfrom pathlib import Path\ntime.sleep(1.0)\nassert Path({str(ready)!r}).exists(), 'not yet'",
        WRITE.format(name="02_second")])
    out = tmp_path / "reports"
    for _ in range(2):
        with pytest.raises(NotebookFailed):
            run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    attempts = json.loads((out / "02_second" / ATTEMPTS_FILE).read_text())["attempts"]
    assert [a["status"] for a in attempts] == ["failed", "failed"] and all(a["seconds"] >= 1.0 for a in attempts)
    ready.touch()
    logged = []
    finished = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=logged.append)
    entry = finished.record["notebooks"][1]
    stopped = sum(a["seconds"] for a in attempts)
    assert entry["earlier_attempts"] == {"count": 2, "seconds": pytest.approx(stopped),
                                         "cpu_seconds": pytest.approx(sum(a["cpu_seconds"] for a in attempts))}
    assert any("resumes after 2 stopped attempt(s)" in line for line in logged), logged
    assert json.loads((out / "02_second" / KEY_FILE).read_text())["earlier_attempts"] == entry["earlier_attempts"]
    assert not (out / "02_second" / ATTEMPTS_FILE).exists()
    # kept by the next run, the section still counts them; the report adds them to the sections' time
    kept = run_study(toy_profile, out, notebooks_dir=toy_notebooks, progress=False, log=lambda m: None)
    assert kept.record["notebooks"][1]["kept"] and kept.record["notebooks"][1]["earlier_attempts"]["count"] == 2
    assert f"after 2 stopped attempts of {stopped:.0f} s" in kept.report_md.read_text()
