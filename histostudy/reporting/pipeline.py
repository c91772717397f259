"""The batch study (``histostudy reproduce``): the notebooks of a profile run through papermill,
each into its section folder, kept where its content key is unchanged, then the report assembled
(docs/report.md, "The batch run")."""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from histostudy.core import SCHEDULER_ENV, SWEEP_CACHE_ENV, atomic_path, cpu_seconds, provenance, shipped_dir
from histostudy.core.provenance import REPO_ROOT

from .interrupts import StudyInterrupted, remove_temporaries, signals_interrupt, stop_kernels
from .profiles import Profile, load_profile, validate_profile
from .report import build_report, load_section, write_run_record
from .section_keys import (
    SectionKey,
    changed_parts,
    earlier_attempts,
    estimate_seconds,
    kept_section,
    record_attempt,
    record_key,
    remove_key,
    section_key,
)

__all__ = ["NotebookFailed", "discover_notebooks", "run_study", "section_stages", "select_notebooks"]

NOTEBOOK_PATTERN = re.compile(r"^\d\d_[A-Za-z0-9_]+\.ipynb$")
#: The study's notebooks: ``notebooks/`` of a checkout, the packaged copy of a wheel
#: (:func:`histostudy.core.shipped_dir`).
DEFAULT_NOTEBOOK_DIR = shipped_dir("notebooks")
_KERNEL_NAME = "histostudy-running-python"
#: The folder of a run's output that keeps its sweeps' finished tasks (:mod:`histostudy.core.sweep_cache`).
SWEEP_CACHE_FOLDER = ".sweep-cache"


class NotebookFailed(RuntimeError):
    """A notebook raised during the batch run; the message names the notebook, the cell and the error.

    Args:
        notebook: the notebook's stem (``"04_pose_estimation"``).
        cell_index: the failed cell, as ``"<index> ('<first line>')"`` counted in the source notebook
            (papermill's injected cells left out), or papermill's own index where the executed copy
            cannot be read.
        error: ``"<exception name>: <value>"``.
        executed_notebook: the executed copy kept with the traceback (``<output>/notebooks/``).
    """

    def __init__(self, notebook: str, cell_index, error: str, executed_notebook: Path):
        self.notebook = notebook
        self.cell_index = cell_index
        self.error = error
        self.executed_notebook = executed_notebook
        super().__init__(f"notebook {notebook} failed at cell {cell_index}: {error} "
                         f"(executed copy kept at {executed_notebook})")


def discover_notebooks(notebooks_dir: str | os.PathLike = DEFAULT_NOTEBOOK_DIR) -> list[Path]:
    """The study notebooks ``NN_name.ipynb`` of a folder, in order.

    Args:
        notebooks_dir: the folder (default :data:`DEFAULT_NOTEBOOK_DIR`: a checkout's ``notebooks/``,
            else the copy packaged in the wheel).

    Returns:
        Their paths, sorted by name.

    Raises:
        ValueError: ``notebooks_dir`` is not a folder, or holds no ``NN_name.ipynb``.
    """
    folder = Path(notebooks_dir)
    if not folder.is_dir():
        raise ValueError(f"notebooks_dir {str(folder)!r} is not a folder (expected a folder of the study's "
                         f"NN_name.ipynb notebooks, such as a checkout's notebooks/)")
    found = sorted(p for p in folder.iterdir() if NOTEBOOK_PATTERN.match(p.name))
    if not found:
        raise ValueError(f"notebooks_dir {str(folder)!r} holds no notebook named NN_name.ipynb")
    return found


def select_notebooks(notebooks: Sequence[Path], only: Sequence[str] | None) -> list[Path]:
    """The notebooks named by ``only``, in run order.

    Args:
        notebooks: the notebooks of the folder (:func:`discover_notebooks`).
        only: names, each a full stem, its number (``"01"``) or its name part; None or empty for all.

    Returns:
        The chosen paths in the order of ``notebooks``, each once.

    Raises:
        ValueError: a name of ``only`` matches no notebook (the message lists those available).
    """
    if not only:
        return list(notebooks)
    chosen: list[Path] = []
    for name in only:
        matches = [p for p in notebooks if name in (p.stem, p.stem[:2], p.stem[3:])]
        if not matches:
            raise ValueError(f"--only {name!r} names no notebook; available: {', '.join(p.stem for p in notebooks)}")
        chosen.extend(m for m in matches if m not in chosen)
    return [p for p in notebooks if p in chosen]


@dataclass
class StudyRun:
    """What :func:`run_study` returns: the run's folder, its ``REPORT.md`` and ``report.html`` and
    the run record written to ``run.json``."""

    output_dir: Path
    report_md: Path
    report_html: Path
    record: dict


def run_study(profile: str | os.PathLike | Profile, output_dir: str | os.PathLike = "reports", *,
              only: Sequence[str] | None = None, notebooks_dir: str | os.PathLike | None = None,
              progress: bool = True, log: Callable[[str], None] | None = None, workers: int = 1,
              sweep_workers: int | None = None, force: bool = False) -> StudyRun:
    """Run the study notebooks of ``profile`` into ``output_dir`` and assemble the report.

    Each notebook ``NN_name.ipynb`` runs with the profile's parameters plus ``output_dir =
    <output>/NN_name`` in a kernel of the running interpreter; its executed copy lands in
    ``<output>/notebooks/``. A section whose content key (:func:`~.section_keys.section_key`) equals
    the one stored when it last finished is kept (``"kept": true`` in ``run.json``); the sweeps keep
    their finished tasks in ``<output>/.sweep-cache`` (:mod:`histostudy.core.sweep_cache`). The log
    estimates each notebook's wall time from the last finished run with the same parameters.

    Args:
        profile: a built-in profile's name (``"smoke"``, ``"standard"``, ``"paper"``), the path of a
            profile's TOML file, or a loaded :class:`~.profiles.Profile`.
        output_dir: the run's folder (created); ``run.json``, ``REPORT.md``, ``report.html`` and one
            folder per section go there.
        only: the notebooks to run, each by full stem, number (``"04"``) or name part; None runs all.
        notebooks_dir: the folder of the ``NN_name.ipynb`` notebooks (default :data:`DEFAULT_NOTEBOOK_DIR`:
            a checkout's ``notebooks/``, else the copy packaged in the wheel; the log names it).
        progress: show papermill's progress bar per notebook.
        log: where the run's lines go (default: stderr).
        workers: how many notebooks run at once, each in its own kernel (1: one after the other).
            The numbers do not depend on it: each notebook takes its seed from the profile.
        sweep_workers: the processes each notebook's Monte-Carlo sweeps run in (a dask local
            cluster; 1: in the kernel), where ``HISTOSTUDY_SCHEDULER`` is unset (set, it wins);
            None: the cores left to each notebook, this machine's usable cores // ``workers``. The
            numbers do not depend on it either (docs/sweeps.md); ``run.json`` records it.
        force: run every notebook again, even one whose finished section is unchanged.

    Returns:
        A ``StudyRun``: ``output_dir`` (resolved), ``report_md`` and ``report_html`` (the paths of
        ``REPORT.md`` and ``report.html``) and ``record`` (the contents of ``run.json``).

    Raises:
        ValueError: ``workers`` or ``sweep_workers`` is not a positive integer; ``profile`` is unknown or its file is
            malformed (:func:`~.profiles.load_profile`); ``notebooks_dir`` holds no notebook; the
            profile does not fit its notebooks (:func:`~.profiles.validate_profile`); ``only`` names
            no notebook. All before anything runs or is written.
        NotebookFailed: a notebook raised; raised after the report of what ran is written (the
            failure named in it). A failed notebook stops new ones from starting; those already
            running finish.
        StudyInterrupted: SIGTERM or SIGINT (likewise ``KeyboardInterrupt``) stopped the run:
            the running kernels are stopped, their temporary files removed, their sections marked
            ``"interrupted"``, and the report written before it is raised.
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer (notebooks run at once), got {workers!r}")
    if sweep_workers is not None and (isinstance(sweep_workers, bool) or not isinstance(sweep_workers, int)
                                      or sweep_workers < 1):
        raise ValueError(f"sweep_workers must be None or a positive integer (processes per notebook's sweeps), "
                         f"got {sweep_workers!r}")
    prof = profile if isinstance(profile, Profile) else load_profile(profile)
    notebooks_dir = Path(notebooks_dir or DEFAULT_NOTEBOOK_DIR)
    found = discover_notebooks(notebooks_dir)
    # Against every notebook of the folder, not the --only subset: a table for a notebook left out
    # of this run is still a valid table, and a misspelt one is wrong whatever runs.
    validate_profile(prof, found)
    notebooks = select_notebooks(found, only)
    out = Path(output_dir).resolve()
    (out / "notebooks").mkdir(parents=True, exist_ok=True)
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    log(f"notebooks: {notebooks_dir.resolve()}")
    record: dict = {
        "profile": prof.name,
        "profile_source": prof.source,
        "seed": prof.seed,
        "notebooks_dir": str(notebooks_dir.resolve()),
        "provenance": provenance(),
        "notebooks": [{"name": p.stem, "status": "pending"} for p in notebooks],
        "failure": None,
    }
    workers = min(workers, len(notebooks))
    scheduler = _sweep_scheduler(workers, sweep_workers)
    record["sweeps"] = scheduler
    log(f"sweeps: {scheduler}" + (f" (${SCHEDULER_ENV})" if os.environ.get(SCHEDULER_ENV, "").strip() else ""))
    tasks = [_NotebookTask(i, len(notebooks), nb_path, entry, prof, out, progress, log, force, workers == 1)
             for i, (nb_path, entry) in enumerate(zip(notebooks, record["notebooks"]), start=1)]
    _estimate(tasks, out, prof.name)
    started = time.perf_counter()
    with signals_interrupt(), _running_kernel() as kernel_name, _sweep_environment(out, scheduler):
        failure = _run_tasks(tasks, kernel_name, workers, record)
    record["wall_seconds"] = time.perf_counter() - started
    write_run_record(out, record)
    md, html_path = build_report(out, record)
    if failure is not None:
        raise failure
    return StudyRun(out, md, html_path, record)


@dataclass
class _NotebookTask:
    """One notebook of a run: its place, its entry of ``run.json`` (updated as it runs) and where
    its section goes."""
    index: int
    count: int
    nb_path: Path
    entry: dict
    profile: Profile
    out: Path
    progress: bool
    log: Callable[[str], None]
    force: bool = False
    #: whether this notebook runs alone, so that the CPU time of the finished kernels is its own
    alone: bool = True
    #: (estimated wall time in s, where it was measured), or None (:func:`_estimate`)
    estimate: tuple[float, str] | None = None
    #: the estimated seconds of this and every later notebook, None where one has no estimate
    left_s: float | None = None
    key: SectionKey | None = None
    #: the stored record of the finished section this run keeps, or None: it runs (:meth:`prepare`)
    kept: dict | None = None
    #: ``time.perf_counter()`` when its notebook started, None before
    started: float | None = None

    @property
    def section_dir(self) -> Path:
        return self.out / self.nb_path.stem

    @property
    def executed_path(self) -> Path:
        return self.out / "notebooks" / self.nb_path.name

    @property
    def params(self) -> dict:
        return self.profile.parameters_for(self.nb_path.stem) | {"output_dir": str(self.section_dir)}

    def prepare(self) -> None:
        """Compute the content key and whether the finished section is kept."""
        self.key = section_key(self.nb_path, self.params)
        self.kept = None if self.force else kept_section(self.section_dir, self.executed_path, self.key)

    def run(self, kernel_name: str) -> NotebookFailed | None:
        """Execute the notebook, or keep its finished section when its content key is unchanged;
        its :class:`NotebookFailed` is returned, not raised."""
        params, name, key, kept = self.params, self.nb_path.stem, self.key, self.kept
        if key is None:
            raise RuntimeError(f"notebook {name}: run() before prepare() computed its content key")
        self.entry.update(output_dir=str(self.section_dir), parameters=params, key=key.key)
        if kept is not None:
            self.entry.update(status="ok", kept=True, seconds=kept["seconds"], cpu_seconds=kept.get("cpu_seconds"),
                              finished_utc=kept.get("finished_utc"))
            if kept.get("earlier_attempts"):
                self.entry["earlier_attempts"] = kept["earlier_attempts"]
            self.entry.update(section_stages(self.section_dir, kept["seconds"], kept.get("cpu_seconds")))
            self.log(f"[{self.index}/{self.count}] {name}: unchanged since {kept.get('finished_utc')} "
                     f"(key {key.key[:12]}), kept ({kept['seconds']:.0f} s then)")
            return None
        why = "--force" if self.force else ", ".join(changed_parts(self.section_dir, key))
        remove_key(self.section_dir)
        attempts = earlier_attempts(self.section_dir, key)
        self.entry.update(status="running", kept=False)
        if attempts is not None:
            self.entry["earlier_attempts"] = attempts
        self.log(f"[{self.index}/{self.count}] {name} (profile {self.profile.name}; runs: {why or 'no finished run'})"
                 + _estimate_text(self.estimate, self.left_s)
                 + (f"; resumes after {attempts['count']} stopped attempt(s) of {_duration(attempts['seconds'])}"
                    if attempts else ""))
        t0, cpu0 = time.perf_counter(), cpu_seconds(own=False)
        self.started = t0
        failure = None
        try:
            _execute(self.nb_path, self.executed_path, params, kernel_name, self.progress)
        except NotebookFailed as exc:
            failure = exc
        finally:
            self.entry["seconds"] = time.perf_counter() - t0
            self.entry["cpu_seconds"] = cpu_seconds(own=False) - cpu0 if self.alone else None
        self.entry["status"] = "ok" if failure is None else "failed"
        if failure is None:
            self.entry.update(section_stages(self.section_dir, self.entry["seconds"], self.entry["cpu_seconds"]))
            record_key(self.section_dir, key, notebook=name, profile=self.profile.name, parameters=params,
                       seconds=self.entry["seconds"], cpu_seconds=self.entry["cpu_seconds"],
                       machine=provenance()["machine"], attempts=attempts)
            self.log(f"      {name} done in {self.entry['seconds']:.1f} s")
        else:
            self._record_attempt("failed")
        return failure

    def _record_attempt(self, status: str) -> None:
        """Keep this stopped attempt's time, which the section's finished run adds up (docs/report.md)."""
        if self.key is None or self.kept or self.started is None:
            return
        # an interrupted kernel's thread may not have returned yet to set its time
        seconds = self.entry.get("seconds", time.perf_counter() - self.started)
        record_attempt(self.section_dir, self.key, status=status, seconds=seconds,
                       cpu_seconds=self.entry.get("cpu_seconds"))

    def interrupted(self, signal_name: str) -> None:
        """Mark the section interrupted and remove what its killed kernel left half-written."""
        remove_temporaries(self.section_dir, self.out / "notebooks")
        self.entry.update(status="interrupted")
        self._record_attempt("interrupted")
        self.log(f"      interrupted by {signal_name}: kernel stopped, section {self.nb_path.stem} marked interrupted")


def section_stages(section_dir, seconds: float, cpu_seconds: float | None) -> dict:
    """A finished section's time by stage, for its entry of ``run.json``.

    Args:
        section_dir: the section's folder, whose ``results.json`` holds the stage times the
            notebook's :class:`~.report.SectionWriter` recorded (``"stages"``).
        seconds: the notebook's wall time, s.
        cpu_seconds: its CPU time (its kernel and their workers), s; None where it is not known
            (notebooks that ran at once).

    Returns:
        ``{"stages": {stage: {"wall_s", "cpu_s", "calls"}}, "other": {"wall_s", "cpu_s"}}``: ``other``
        is the notebook's time outside every stage, the stages' sum taken from its wall and CPU time
        (at least 0: a stage's time adds up the processes that ran it, which a sweep's workers can
        make more than the notebook's; None where the CPU time is not known); ``{}`` where
        ``results.json`` records no stages (a section of an earlier version, or unreadable).
    """
    try:
        stages = load_section(section_dir).get("stages")
    except (OSError, ValueError, AttributeError):
        return {}
    if not isinstance(stages, dict):
        return {}
    wall = sum(float(s.get("wall_s", 0.0)) for s in stages.values())
    cpu = sum(float(s.get("cpu_s", 0.0)) for s in stages.values())
    return {"stages": stages, "other": {"wall_s": max(0.0, float(seconds) - wall),
                                        "cpu_s": None if cpu_seconds is None else max(0.0, float(cpu_seconds) - cpu)}}


def _estimate(tasks: list[_NotebookTask], out: Path, profile_name: str) -> None:
    """Set each task's estimate from the last finished run with its parameters (this output folder,
    then the published run of the profile), and the time left from it on."""
    places = [out, REPO_ROOT / "docs" / "results" / profile_name]
    left: float | None = 0.0
    for task in reversed(tasks):
        task.prepare()
        task.estimate = estimate_seconds(task.nb_path.stem, task.params, places)
        if task.kept is None:
            left = None if left is None or task.estimate is None else left + task.estimate[0]
        task.left_s = left


def _estimate_text(estimate: tuple[float, str] | None, left_s: float | None) -> str:
    if estimate is None:
        return "; no earlier run with these parameters to estimate its time from"
    text = f"; about {_duration(estimate[0])} by {estimate[1]}"
    return text + (f", about {_duration(left_s)} left for the run" if left_s is not None else "")


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"


def _run_tasks(tasks: list[_NotebookTask], kernel_name: str, workers: int, record: dict):
    """Run ``tasks`` on ``workers`` threads (each drives one kernel), in order of start; returns the
    first failure (a :class:`NotebookFailed`, or the interruption), None when every notebook ran."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    waiting: list[_NotebookTask] = list(tasks)
    running: dict = {}  # future -> its _NotebookTask
    failure: BaseException | None = None
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="notebook")
    try:
        while waiting or running:
            while waiting and failure is None and len(running) < workers:
                task = waiting.pop(0)
                running[pool.submit(task.run, kernel_name)] = task
            if not running:
                break
            # a timeout, so that SIGINT and SIGTERM reach the main thread between waits
            done, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
            for future in done:
                running.pop(future)
                result = future.result()
                if result is not None and failure is None:
                    record["failure"] = {"notebook": result.notebook, "cell_index": result.cell_index,
                                         "error": result.error, "executed_notebook": str(result.executed_notebook)}
                    failure = result
    except (KeyboardInterrupt, StudyInterrupted) as exc:
        signal_name = getattr(exc, "signal_name", "SIGINT")
        stop_kernels()
        # the threads return once their kernels are gone; what they raise then is the interruption's
        wait(running, timeout=30)
        for task in running.values():
            task.interrupted(signal_name)
        first = min(running.values(), key=lambda t: t.index, default=None)
        record["failure"] = {"notebook": first.nb_path.stem if first else None, "cell_index": None,
                             "error": f"interrupted by {signal_name}", "executed_notebook": None}
        failure = exc
    except BaseException:
        stop_kernels()  # an error of the runner itself: no kernel outlives it
        raise
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
    return failure


def _execute(nb_path: Path, executed_path: Path, params: dict, kernel_name: str, progress: bool) -> None:
    import papermill
    from papermill.exceptions import PapermillExecutionError

    with atomic_path(executed_path) as tmp:
        try:
            papermill.execute_notebook(str(nb_path), str(tmp), parameters=params, kernel_name=kernel_name,
                                       progress_bar=progress, cwd=str(nb_path.parent), log_output=False)
        except PapermillExecutionError as exc:
            # Keep the executed copy with the traceback: rename it into place before reporting.
            os.replace(tmp, executed_path)
            cell = _failed_cell(executed_path)
            where = f"{cell[0]} ({cell[1]!r})" if cell else exc.cell_index
            raise NotebookFailed(nb_path.stem, where, f"{exc.ename}: {exc.evalue}", executed_path) from None


def _failed_cell(executed_path: Path) -> tuple[int, str] | None:
    """``(index, first source line)`` of the cell that raised, indexed as in the source notebook.

    Papermill's own index counts the cells it inserts (injected parameters, error banners); users
    look for the cell in the notebook they opened, so those are skipped.
    """
    try:
        nb = json.loads(executed_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    index = 0
    for cell in nb.get("cells", []):
        tags = cell.get("metadata", {}).get("tags", [])
        if "papermill-error-cell-tag" in tags or "injected-parameters" in tags:
            continue
        if any(o.get("output_type") == "error" for o in cell.get("outputs", [])):
            source = "".join(cell.get("source", ""))
            return index, (source.strip().splitlines() or [""])[0][:80]
        index += 1
    return None


def _sweep_scheduler(workers: int, sweep_workers: int | None) -> str:
    """Where the kernels' sweeps run: ``$HISTOSTUDY_SCHEDULER`` where set, else ``"local:<n>"`` for
    ``n`` = ``sweep_workers`` (default: the usable cores // ``workers``) of 2 or more, else
    ``"sequential"``."""
    if os.environ.get(SCHEDULER_ENV, "").strip():
        return os.environ[SCHEDULER_ENV].strip()
    if sweep_workers is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        sweep_workers = max(1, cores // workers)
    return f"local:{sweep_workers}" if sweep_workers > 1 else "sequential"


class _sweep_environment:
    """Context manager: the kernels' sweeps keep their finished tasks in ``<output>/.sweep-cache``
    (:data:`~histostudy.core.SWEEP_CACHE_ENV`), unless the variable names a folder already, so that
    a section stopped half-way redoes only the tasks that did not finish; and run on ``scheduler``
    (:data:`~histostudy.core.SCHEDULER_ENV`, the environment the kernels inherit)."""

    def __init__(self, out: Path, scheduler: str):
        self._values = {SWEEP_CACHE_ENV: str(out / SWEEP_CACHE_FOLDER), SCHEDULER_ENV: scheduler}

    def __enter__(self):
        self._old = {name: os.environ.get(name) for name in self._values}
        for name, value in self._values.items():
            if not (self._old[name] or "").strip():
                os.environ[name] = value
        return self

    def __exit__(self, *exc):
        for name, old in self._old.items():
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old
        return False


class _running_kernel:
    """Context manager: a kernelspec for ``sys.executable`` on a temporary ``JUPYTER_PATH``."""

    def __enter__(self) -> str:
        self._tmp = tempfile.TemporaryDirectory(prefix="histostudy-kernel-")
        spec_dir = Path(self._tmp.name) / "kernels" / _KERNEL_NAME
        spec_dir.mkdir(parents=True)
        spec = {"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": "histostudy (running interpreter)", "language": "python"}
        (spec_dir / "kernel.json").write_text(json.dumps(spec), encoding="utf-8")
        self._old = os.environ.get("JUPYTER_PATH")
        os.environ["JUPYTER_PATH"] = os.pathsep.join(filter(None, [self._tmp.name, self._old]))
        return _KERNEL_NAME

    def __exit__(self, *exc):
        if self._old is None:
            os.environ.pop("JUPYTER_PATH", None)
        else:
            os.environ["JUPYTER_PATH"] = self._old
        self._tmp.cleanup()
        return False
