"""Results and report: what a study notebook records, and the report assembled from those records.

A notebook never relies on its own cell outputs to reach the report. It records through a
:class:`SectionWriter` — values, comparisons with the paper, tables (CSV + Markdown), figures
(PNG), text, and what stands in for the lab — and :meth:`SectionWriter.save` writes
``<output>/<section>/results.json``. After the run, :func:`build_report` reads every section's
``results.json`` and writes ``REPORT.md`` and ``report.html``. Every file is written atomically.
"""

from __future__ import annotations

import contextlib
import html
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path, atomic_write_json, atomic_write_text, provenance, to_jsonable
from .paper import PAPER, paper_value

__all__ = ["RESULTS_FILE", "SectionWriter", "build_report", "format_measure", "load_section", "results_coverage"]

RESULTS_FILE = "results.json"
RUN_FILE = "run.json"


def format_measure(mean, sd=None, unit: str = "", digits: int = 2) -> str:
    """``"1.38 ± 0.54 mm"``; strings pass through; None/NaN read as ``"n/a"``."""
    if mean is None:
        return "n/a"
    if isinstance(mean, str):
        return f"{mean} {unit}".strip() if unit and not mean.endswith(unit) else mean
    if isinstance(mean, (bool, np.bool_)):
        return str(bool(mean))
    if isinstance(mean, (int, np.integer)) and sd is None:
        return f"{int(mean)} {unit}".strip()
    if not np.isfinite(float(mean)):
        return "n/a"
    text = f"{float(mean):.{digits}f}"
    if sd is not None and np.isfinite(float(sd)):
        text += f" ± {float(sd):.{digits}f}"
    return f"{text} {unit}".strip()


@dataclass
class _Entry:
    name: str
    caption: str
    path: str


class SectionWriter:
    """Collects one notebook's results and writes them under ``output_dir``.

    Args:
        output_dir: the section's folder (papermill passes ``reports/<notebook stem>``).
        section: the notebook stem, e.g. ``"01_transducer_and_projections"``.
        title: the report heading.
        profile, seed: the run's profile name and seed (recorded).
        parameters: the notebook's parameters (recorded).
    """

    def __init__(self, output_dir, section: str, title: str, *, profile: str, seed: int,
                 parameters: dict | None = None):
        self.output_dir = Path(output_dir)
        self.section = section
        self.title = title
        self.profile = profile
        self.seed = seed
        self.parameters = dict(parameters or {})
        self.values: dict = {}
        self.comparisons: list[dict] = []
        self.tables: list[_Entry] = []
        self.figures: list[_Entry] = []
        self.paragraphs: list[str] = []
        self.stand_ins: list[dict] = []
        self.timings_s: dict[str, float] = {}
        self._started = time.perf_counter()

    # --- recording ----------------------------------------------------------------------------

    @contextlib.contextmanager
    def timer(self, name: str):
        """Record the wall time of the block, in seconds, under ``name``."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[name] = time.perf_counter() - t0

    def value(self, key: str, value) -> None:
        """Record a measured value (any JSON-able structure) under ``key``."""
        self.values[key] = value

    def compare(self, key: str, label: str, ours, *, ours_sd=None, unit: str = "", digits: int = 2,
                paper_key: str | None = None, note: str = "") -> dict:
        """Set a reproduced number beside the paper's value ``paper_key`` (default ``key``).

        ``ours`` may be a number, ``(mean, sd)`` or a string. ``paper_key=""`` records a figure
        the paper does not report (the report shows "not reported").
        """
        if isinstance(ours, tuple) and len(ours) == 2 and ours_sd is None:
            ours, ours_sd = ours
        pk = key if paper_key is None else paper_key
        paper = paper_value(pk) if pk else None
        row = {
            "key": key,
            "paper_key": pk or None,
            "label": label,
            "ours": to_jsonable(ours),
            "ours_sd": to_jsonable(ours_sd),
            "unit": unit,
            "ours_text": format_measure(ours, ours_sd, unit, digits),
            "paper_text": paper.format() if paper else "not reported",
            "paper_where": paper.where if paper else "",
            "note": note,
        }
        self.comparisons.append(row)
        return row

    def text(self, markdown: str) -> None:
        """A paragraph of Markdown for the report."""
        self.paragraphs.append(markdown.strip())

    def stand_in(self, lab: str, synthetic: str) -> None:
        """Name what in this synthetic study stands in for what the paper had in the lab."""
        self.stand_ins.append({"lab": lab, "synthetic": synthetic})

    def table(self, name: str, df, caption: str = "", *, index: bool = False, digits: int = 3):
        """Write a pandas DataFrame as ``tables/<name>.csv`` and ``.md``; returns the DataFrame."""
        _check_name(name)
        tables = self.output_dir / "tables"
        csv_path, md_path = tables / f"{name}.csv", tables / f"{name}.md"
        with atomic_path(csv_path) as tmp:
            df.to_csv(tmp, index=index)
        atomic_write_text(md_path, df.to_markdown(index=index, floatfmt=f".{digits}f") + "\n")
        self.tables.append(_Entry(name, caption, f"tables/{name}.md"))
        return df

    def figure(self, name: str, fig, caption: str = "", *, dpi: int = 110) -> Path:
        """Save a matplotlib figure as ``figures/<name>.png``."""
        _check_name(name)
        path = self.output_dir / "figures" / f"{name}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
        self.figures.append(_Entry(name, caption, f"figures/{name}.png"))
        return path

    def image(self, name: str, rgb: np.ndarray, caption: str = "") -> Path:
        """Save an RGB uint8 array (e.g. a pyvista screenshot) as ``figures/<name>.png``."""
        import cv2

        _check_name(name)
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] not in (3, 4) or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be an (h, w, 3|4) uint8 image, got shape {rgb.shape} dtype {rgb.dtype}")
        path = self.output_dir / "figures" / f"{name}.png"
        ok, data = cv2.imencode(".png", cv2.cvtColor(rgb[..., :3], cv2.COLOR_RGB2BGR))
        if not ok:
            raise RuntimeError(f"PNG encoding of figure {name!r} failed")
        with atomic_path(path) as tmp:
            tmp.write_bytes(data.tobytes())
        self.figures.append(_Entry(name, caption, f"figures/{name}.png"))
        return path

    # --- output -------------------------------------------------------------------------------

    def save(self) -> Path:
        """Write ``results.json`` (atomically) and return its path."""
        self.timings_s.setdefault("total", time.perf_counter() - self._started)
        record = {
            "section": self.section,
            "title": self.title,
            "profile": self.profile,
            "seed": self.seed,
            "parameters": self.parameters,
            "values": self.values,
            "comparisons": self.comparisons,
            "tables": [vars(t) for t in self.tables],
            "figures": [vars(f) for f in self.figures],
            "text": self.paragraphs,
            "stand_ins": self.stand_ins,
            "timings_s": self.timings_s,
            "provenance": provenance(),
        }
        return atomic_write_json(self.output_dir / RESULTS_FILE, record)


def _check_name(name: str) -> None:
    if not name or not all(c.isalnum() or c in "_-." for c in name):
        raise ValueError(f"name must be letters, digits, '_', '-' or '.', got {name!r}")


def load_section(section_dir) -> dict:
    """The ``results.json`` of one section folder."""
    path = Path(section_dir) / RESULTS_FILE
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


# --- report assembly ---------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
line-height:1.45;color:#222}
table{border-collapse:collapse;margin:.8em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.3em .6em;text-align:left}
th{background:#f3f3f3}
img{max-width:100%;border:1px solid #ddd;margin:.4em 0}
code{background:#f6f6f6;padding:0 .2em}
.fail{background:#fee;border:1px solid #c00;padding:.6em}
"""


def build_report(output_dir, run: dict | None = None) -> tuple[Path, Path]:
    """Assemble ``REPORT.md`` and ``report.html`` in ``output_dir`` from the sections' results.

    ``run`` is the pipeline's run record (profile, notebook order, timings, failure); by default it
    is read from ``output_dir/run.json``. Sections are taken in the run's order; a section whose
    notebook did not finish is named with its failure.
    """
    out = Path(output_dir)
    if run is None:
        with open(out / RUN_FILE, encoding="utf-8") as fh:
            run = json.load(fh)
    md = _report_markdown(out, run)
    md_path = atomic_write_text(out / "REPORT.md", md)
    import markdown as markdown_lib

    body = markdown_lib.markdown(md, extensions=["tables", "fenced_code"])
    page = (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>histostudy report ({html.escape(str(run.get('profile', '')))})</title>"
            f"<style>{_CSS}</style></head><body>\n{body}\n</body></html>\n")
    html_path = atomic_write_text(out / "report.html", page)
    return md_path, html_path


def _report_markdown(out: Path, run: dict) -> str:
    lines = [
        "# histostudy: X-ray C-arm guided automatic targeting for histotripsy, reproduced",
        "",
        "Reproduction on synthetic data of Wagner et al., *An X-ray C-arm Guided Automatic Targeting "
        "System for Histotripsy*, IEEE TBME 70(2):592-602, 2023. Each reproduced figure stands beside "
        "the paper's value; the paper's experiments used a physical transducer, porcine and phantom "
        "studies and a UR5e, and each section names what stands in for them here.",
        "",
        f"- Profile: `{run.get('profile')}` (seed {run.get('seed')})",
        f"- Commit: `{run.get('provenance', {}).get('git_commit', 'unknown')}`",
        f"- Created (UTC): {run.get('provenance', {}).get('created_utc', '')}",
        f"- Notebooks: {', '.join(n['name'] for n in run.get('notebooks', []))}",
        "",
    ]
    failure = run.get("failure")
    if failure and failure.get("executed_notebook") is None:
        lines += [f"> **Run stopped:** notebook `{failure['notebook']}` {failure.get('error')}; its kernel was "
                  "stopped and its section is incomplete.", ""]
    elif failure:
        lines += [f"> **Run failed:** notebook `{failure['notebook']}` at cell {failure.get('cell_index')}: "
                  f"{failure.get('error')}. Its executed copy is `{failure.get('executed_notebook')}`.", ""]
    sections = {}
    for nb in run.get("notebooks", []):
        name = nb["name"]
        section_dir = out / name
        # a section that did not finish in this run may hold an earlier run's results: not shown
        if nb.get("status", "ok") != "ok" or not (section_dir / RESULTS_FILE).is_file():
            lines += [f"## {name}", "", f"*No results: status {nb.get('status', 'not run')}.*", ""]
            continue
        sections[name] = load_section(section_dir)
        lines += _section_markdown(name, sections[name], nb)
    coverage = results_coverage(sections)
    lines += ["## The paper's results and their reproduced twins", "",
              "Every number of the paper's §III (Tables I and II, the statistics in the text, the targeting "
              "paragraph) and the abstract, and the section of this report that reproduces it "
              f"({sum(1 for c in coverage if c['sections'])} of {len(coverage)} in this run).", "",
              "| Paper value | Where | Reproduced in |", "|---|---|---|"]
    for c in coverage:
        where = ", ".join(f"`{name}`" for name in c["sections"]) or "**not in this run**"
        lines.append(f"| {_md_cell(c['key'])}: {_md_cell(c['paper_text'])} | {_md_cell(c['where'])} | {where} |")
    lines.append("")
    versions = run.get("provenance", {}).get("versions", {})
    if versions:
        lines += ["## Software", "", "| package | version |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in versions.items()]
        lines.append("")
    return "\n".join(lines)


def results_coverage(sections: dict[str, dict]) -> list[dict]:
    """Which section compares each of the paper's results (§III, Tables I-II, abstract).

    ``sections``: section name -> its loaded results (:func:`load_section`). Returns one row per
    paper result (``key``, ``paper_text``, ``where``, ``sections``: the names of the sections with a
    comparison against it), in :data:`histostudy.reporting.paper.PAPER` order. The report lists them so
    that a result the study does not reproduce is seen, not silently missing.
    """
    rows = []
    for key, value in PAPER.items():
        if not any(tag in value.where for tag in ("§III", "Table", "abstract")):
            continue
        found = [name for name, res in sections.items()
                 if any(c.get("paper_key", c.get("key")) == key for c in res.get("comparisons", []))]
        rows.append({"key": key, "paper_text": value.format(), "where": value.where, "sections": found})
    return rows


def _section_markdown(name: str, res: dict, nb: dict) -> list[str]:
    lines = [f"## {res.get('title', name)}", ""]
    lines += [f"*Notebook `{name}` — executed copy `notebooks/{name}.ipynb`, "
              f"{nb.get('seconds', float('nan')):.1f} s.*", ""]
    for para in res.get("text", []):
        lines += [para, ""]
    comps = res.get("comparisons", [])
    if comps:
        lines += ["| Quantity | This study | Paper | Source | Note |", "|---|---|---|---|---|"]
        for c in comps:
            cells = [c["label"], c["ours_text"], c["paper_text"], c.get("paper_where", ""), c.get("note", "")]
            lines.append("| " + " | ".join(_md_cell(x) for x in cells) + " |")
        lines.append("")
    for t in res.get("tables", []):
        path = Path(nb.get("output_dir", "")) / t["path"] if nb.get("output_dir") else None
        md_table = _read_text(path) if path else None
        lines += [f"**{t['caption'] or t['name']}**", "", md_table or f"(table `{t['path']}` missing)", ""]
    for f in res.get("figures", []):
        lines += [f"![{f['caption'] or f['name']}]({name}/{f['path']})", "", f"*{f['caption']}*" if f["caption"] else "", ""]
    stand_ins = res.get("stand_ins", [])
    if stand_ins:
        lines += ["What stands in for the lab:", ""]
        lines += [f"- {s['lab']} → {s['synthetic']}" for s in stand_ins]
        lines.append("")
    timings = res.get("timings_s", {})
    if timings:
        lines.append("Timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
        lines.append("")
    return lines


def _md_cell(x) -> str:
    return str(x).replace("|", "\\|").replace("\n", " ")


def _read_text(path: Path | None) -> str | None:
    try:
        return Path(path).read_text(encoding="utf-8").strip()
    except OSError:
        return None


def write_run_record(output_dir, run: dict) -> Path:
    """Write the pipeline's run record ``run.json``."""
    return atomic_write_json(Path(output_dir) / RUN_FILE, run)
