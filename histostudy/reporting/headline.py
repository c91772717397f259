"""The report's first screen: the profile's banner (what kind of run it is, its study sizes against
the paper's), the headline table of the paper's key results (:data:`HEADLINE_KEYS`) beside their
reproduction, the contents, and the facts of the run with its time by stage (docs/report.md, "The
first screen")."""

from __future__ import annotations

from histostudy.core import STAGES

from .markdown import Markdown, md_code, md_escape, md_link, md_table
from .paper import PAPER
from .twins import TWINS_ANCHOR, TWINS_HEADING, section_anchor, status_markdown

__all__ = ["CONTENTS_ANCHOR", "HEADLINE_ANCHOR", "HEADLINE_KEYS", "SOFTWARE_ANCHOR", "contents_markdown",
           "headline_markdown", "profile_banner", "run_facts", "stage_table"]

#: The paper's key results, in the order of the first screen's table.
HEADLINE_KEYS = ("seg.global_accuracy", "table1.screws.precision", "table1.screws.recall", "table1.screws.iou",
                 "table1.screws.accuracy", "angles.azimuth.mae", "angles.elevation.mae",
                 "table2.center_mae.overall", "targeting.euclidean")
HEADLINE_ANCHOR, CONTENTS_ANCHOR, SOFTWARE_ANCHOR = "at-a-glance", "contents", "software"

_TITLES = {
    "smoke": ("WARNING", "Smoke run: it exercises the pipeline; it is not a reproduction."),
    "standard": ("NOTE", "Standard run: a reproduction at the paper's study sizes, on synthetic data."),
    "paper": ("NOTE", "Paper run: a reproduction with the paper's hyper-parameters and study sizes, on synthetic "
                      "data."),
}
_SMOKE_NOTE = ("Means over so few samples, and SDs over a single experiment (± 0.00), say nothing about the "
               "method: the statuses below only show that every stage runs. The `standard` profile runs the "
               "paper's study sizes.")
# (notebook number, parameter, what it counts, the paper's count)
_SIZES = (("02", "n_eval_images", "evaluation frames", "seg.n_images"),
          ("04", "n_experiments", "pose experiments", "pose.n_studies"),
          ("05", "n_experiments", "targeting experiments", "targeting.n_studies"))


def profile_banner(run: dict, description: str = "") -> list[str]:
    """The banner's Markdown lines: a GitHub alert (``> [!WARNING]`` for the smoke profile,
    ``> [!NOTE]`` otherwise) naming the profile, its ``description`` and the run's study sizes."""
    name = str(run.get("profile", ""))
    kind, title = _TITLES.get(name, ("NOTE", f"Profile {name}: a custom run; its study sizes decide "
                                             "whether it reproduces the paper."))
    body = [f"**{md_escape(title)}**"]
    if description:
        body.append(md_escape(description.rstrip(".") + "."))
    sizes = _study_sizes(run)
    if sizes:
        body.append(f"In this run, {md_escape(sizes)}.")
    if name == "smoke":
        body.append(Markdown(_SMOKE_NOTE))
    return [f"> [!{kind}]", "> " + " ".join(body), ""]


def _study_sizes(run: dict) -> str:
    parts = []
    for number, parameter, what, paper_key in _SIZES:
        nb = next((n for n in run.get("notebooks", []) if n["name"][:2] == number), None)
        value = (nb or {}).get("parameters", {}).get(parameter)
        if value is not None:
            parts.append(f"{what}: {value} (the paper: {PAPER[paper_key].format()})")
    return "; ".join(parts)


def headline_markdown(coverage: list[dict]) -> list[str]:
    """The headline table (:data:`HEADLINE_KEYS`) and its legend, as Markdown lines."""
    by_key = {row["key"]: row for row in coverage}
    rows = []
    for key in HEADLINE_KEYS:
        row, value = by_key[key], PAPER[key]
        c, a = row["comparison"], row["agreement"]
        label = f"{value.label[:1].upper()}{value.label[1:]} ({value.where})"
        result = md_link(label, section_anchor(row["section"])) if row["section"] else label
        rows.append([result, value.format(), c["ours_text"] if c else "—", a.difference_text() if a else "—",
                     status_markdown(row)])
    legend = ("A number **agrees** when it is within the paper's SD of the paper's value, **differs** beyond it, "
              "and is ⚠ **far off** beyond three SDs; it is **better than the paper** where it differs in the "
              "direction this study is expected to, for the reason given (a pose or targeting error without "
              "the lab's error sources). *why* links to the section's sentence on a known cause of the "
              "difference, and to what stands in for the lab there. Every "
              f"other number of the paper is in {md_link(TWINS_HEADING.lower(), TWINS_ANCHOR)}.")
    return [md_table(["Paper result", "Paper", "This run", "Difference", "Status"], rows), "", legend, ""]


def contents_markdown(entries: list[tuple[str, str]]) -> list[str]:
    """The table of contents: ``entries`` of (title, anchor), as a Markdown list under a heading."""
    lines = [f'<a id="{CONTENTS_ANCHOR}"></a>', "", "## Contents", ""]
    lines += [f"- {md_link(title, anchor)}" for title, anchor in entries]
    return lines + [""]


def run_facts(run: dict) -> list[str]:
    """Profile, seed, commit, creation time, machine, wall time, where the sweeps ran and the
    notebooks with their status and wall time (kept: finished by an earlier run with the same
    content key), as a Markdown list, then the sections' time by stage (:func:`stage_table`) where
    the run recorded it."""
    prov = run.get("provenance", {})
    notebooks = ", ".join(f"{md_code(n['name'])} ({md_escape(n.get('status', 'pending'))}"
                          + (", kept" if n.get("kept") else "")
                          + (f", {n['seconds']:.0f} s" if isinstance(n.get("seconds"), (int, float)) else "")
                          + _attempts_text(n) + ")"
                          for n in run.get("notebooks", []))
    lines = [f"- Profile: {md_code(run.get('profile'))} (seed {md_escape(run.get('seed'))})",
             f"- Commit: {md_code(prov.get('git_commit', 'unknown'))}",
             f"- Created (UTC): {md_escape(prov.get('created_utc', ''))}"]
    machine = prov.get("machine") or {}
    if machine:
        flags = machine.get("isa_flags") or {}
        isa = ", ".join(name for name, present in flags.items() if present) or "none of " + ", ".join(flags)
        restriction = machine.get("isa_restriction") or {}
        lines.append(f"- Machine: {md_escape(machine.get('cpu_model', 'unknown CPU'))}, "
                     f"{md_escape(machine.get('cpus'))} cores; ISA {md_escape(isa)}"
                     + (f" (held to {md_escape(' '.join(f'{k}={v}' for k, v in restriction.items()))})"
                        if restriction else ""))
    timed = [n for n in run.get("notebooks", []) if isinstance(n.get("seconds"), (int, float))]
    if timed:
        stopped = sum(_attempts_seconds(n) for n in timed)
        total = sum(n["seconds"] for n in timed) + stopped
        kept = sum(n["seconds"] + _attempts_seconds(n) for n in timed if n.get("kept"))
        wall = run.get("wall_seconds")
        lines.append(f"- Wall time of the sections: {_hours(total)}"
                     + (f", of which {_hours(kept)} in earlier runs whose sections were kept" if kept else "")
                     + (f"; {_hours(stopped)} of the total in stopped attempts of resumed sections" if stopped else "")
                     + (f"; this run: {_hours(wall)}" if isinstance(wall, (int, float)) else ""))
    if run.get("sweeps"):
        lines.append(f"- Sweeps ran on: {md_code(run['sweeps'])} (docs/sweeps.md; the numbers do not depend on it)")
    lines += [f"- Notebooks: {notebooks}", ""]
    table = stage_table(run)
    if table is not None:
        header, rows, unit = table
        lines += [f"Time by stage, wall / CPU in {unit} (a stage's time adds up the processes that ran it, a "
                  "sweep's workers included; other: the section's time outside every stage):", "",
                  md_table(header, rows, ["l"] + ["r"] * (len(header) - 1)), ""]
    return lines


def _attempts_seconds(notebook: dict) -> float:
    """The wall time (s) of a section's stopped attempts before the run that finished it."""
    attempts = notebook.get("earlier_attempts") or {}
    seconds = attempts.get("seconds")
    return float(seconds) if isinstance(seconds, (int, float)) else 0.0


def _attempts_text(notebook: dict) -> str:
    attempts = notebook.get("earlier_attempts") or {}
    if not attempts.get("count"):
        return ""
    return (f", after {attempts['count']} stopped attempt{'s' if attempts['count'] != 1 else ''} of "
            f"{_attempts_seconds(notebook):.0f} s")


def stage_table(run: dict) -> tuple[list[str], list[list[str]], str] | None:
    """The sections' time by stage (``run.json``'s ``stages`` and ``other`` per notebook).

    Args:
        run: the run record.

    Returns:
        ``(header, rows, unit)``: a row per timed notebook and one for all of them, a column per stage
        of :data:`histostudy.core.STAGES` that any of them recorded, then other and total; each cell
        ``"wall / CPU"`` in ``unit`` (``"s"``, ``"min"`` or ``"h"``, by the longest section), ``"—"``
        for a stage the section did not enter, ``"n/a"`` for what is not known (a kept section of a
        version that recorded no stages; the CPU time of notebooks run at once). None where no
        notebook recorded its stages.
    """
    timed = [n for n in run.get("notebooks", []) if isinstance(n.get("seconds"), (int, float))]
    if not any(isinstance(n.get("stages"), dict) for n in timed):
        return None
    used = [s for s in STAGES if any(s in (n.get("stages") or {}) for n in timed)]
    longest = max(n["seconds"] for n in timed)
    unit, scale, digits = ("s", 1.0, 1) if longest < 120 else ("min", 60.0, 1) if longest < 7200 else ("h", 3600.0, 2)

    def cell(times) -> str:
        if times is None:
            return "—"
        if all(v is None for v in times):
            return "n/a"
        return " / ".join("n/a" if v is None else f"{v / scale:.{digits}f}" for v in times)

    rows: list = []
    sums: list[tuple] = [(0.0, 0.0)] * (len(used) + 2)
    for n in timed:
        stages, other = n.get("stages"), n.get("other") or {}
        times = [_stage_times(stages, s) for s in used]
        times += [(other.get("wall_s"), other.get("cpu_s")), (n["seconds"], n.get("cpu_seconds"))]
        sums = [tuple(None if a is None or b is None else a + b for a, b in zip(total, t or (0.0, 0.0)))
                for total, t in zip(sums, times)]
        rows.append([n["name"] + (" (kept)" if n.get("kept") else ""), *map(cell, times)])
    rows.append(["all sections", *map(cell, sums)])
    return ["Section", *used, "other", "total"], rows, unit


def _stage_times(stages, name: str) -> tuple | None:
    """``(wall_s, cpu_s)`` of stage ``name`` in a section's ``stages``: None where the section did not
    enter it, ``(None, None)`` where it recorded no stages."""
    if not isinstance(stages, dict):
        return (None, None)
    entry = stages.get(name)
    return None if entry is None else (entry.get("wall_s"), entry.get("cpu_s"))


def _hours(seconds: float) -> str:
    minutes = seconds / 60
    return f"{seconds:.0f} s" if minutes < 2 else f"{minutes:.1f} min" if minutes < 120 else f"{minutes / 60:.2f} h"
