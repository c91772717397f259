"""Results and report: a notebook records through a :class:`SectionWriter` into
``<output>/<section>/results.json``, and :func:`build_report` assembles ``REPORT.md`` and
``report.html`` from those records (docs/report.md). Every file is written atomically."""

from __future__ import annotations

import contextlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from histostudy.core import (
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    provenance,
    stage,
    stage_delta,
    stage_totals,
    to_jsonable,
)

from .agreement import FAR_OFF, NOT_JUDGED, judge
from .expected import BETTER, as_sentence, known_cause, section_causes
from .headline import SOFTWARE_ANCHOR, contents_markdown, headline_markdown, profile_banner, run_facts
from .markdown import dataframe_markdown, md_code, md_escape, md_table
from .pages import SECTION_PAGE, anchors_of, relink, shorten_table
from .paper import PAPER, paper_value
from .profiles import load_profile
from .report_html import render_html
from .twins import (
    TWINS_ANCHOR,
    TWINS_HEADING,
    results_coverage,
    section_anchor,
    stand_ins_anchor,
    twins_markdown,
    why_anchor,
)

__all__ = ["RESULTS_FILE", "SectionWriter", "build_report", "format_measure", "load_section"]

RESULTS_FILE = "results.json"

#: How a section's first line names its renderer, by its ``splat_device`` parameter (docs/imaging.md).
SPLAT_RENDERERS = {"numpy": "the numpy reference", "cpu": "the compiled kernel (CPU)", "cuda": "torch on CUDA",
                   "auto": "torch on CUDA where present, else the compiled kernel"}
RUN_FILE = "run.json"


def format_measure(mean, sd=None, unit: str = "", digits: int = 2) -> str:
    """A measured value as the report prints it: ``"1.38 ± 0.54 mm"``.

    Args:
        mean: a number, a string (passed through, ``unit`` appended unless it ends with it), a bool,
            or None.
        sd: the standard deviation (same unit), or None; left out when not finite.
        unit: appended after a space ("" for none).
        digits: decimals of a float ``mean`` and ``sd`` (an int without ``sd`` prints whole).

    Returns:
        The text; ``"n/a"`` for None or a non-finite ``mean``.
    """
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
    """Collects one notebook's results and writes them under ``output_dir``: values, comparisons
    with the paper, tables (CSV + Markdown), figures (PNG), text and what stands in for the lab;
    :meth:`save` writes ``results.json``, with the time charged to each stage of
    :data:`histostudy.core.STAGES` since the writer was made (``"stages"``). Writing tables, figures
    and ``results.json`` is itself the ``report`` stage.

    Args:
        output_dir: the section's folder (papermill passes ``reports/<notebook stem>``).
        section: the notebook stem, e.g. ``"01_transducer_and_projections"``.
        title: the report heading.
        profile: the run's profile name (recorded).
        seed: the run's seed (recorded).
        parameters: the notebook's parameters (recorded; copied).
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
        self._stages_before = stage_totals()

    # --- recording ----------------------------------------------------------------------------

    @contextlib.contextmanager
    def timer(self, name: str):
        """Context manager: record the wall time of the block (s) under ``name`` in ``timings_s``.

        Args:
            name: the timing's name in the report.
        """
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.timings_s[name] = time.perf_counter() - t0

    def value(self, key: str, value) -> None:
        """Record a measured value under ``key`` in ``results.json``'s ``values``.

        Args:
            key: the value's name.
            value: any structure :func:`histostudy.core.to_jsonable` can write.
        """
        self.values[key] = value

    def compare(self, key: str, label: str, ours, *, ours_sd=None, unit: str = "", digits: int = 2,
                paper_key: str | None = None, note: str = "") -> dict:
        """Set a reproduced number beside the paper's value (a row of the section's comparison table).

        Args:
            key: the comparison's key.
            label: the row's quantity, for a reader.
            ours: a number, ``(mean, sd)`` or a string.
            ours_sd: the SD (same unit as ``ours``), when ``ours`` is a number.
            unit: the unit of ``ours`` (``"mm"``, ``"deg"``, ``"%"``), which the paper's must match to
                be judged.
            digits: decimals in the printed value.
            paper_key: the key of :data:`~.paper.PAPER` to compare with (default ``key``); ``""`` for a
                figure the paper does not report (shown "not reported").
            note: a remark for the row.

        Returns:
            The recorded row (a dict).

        Raises:
            KeyError: ``paper_key`` (or ``key``) is not a key of :data:`~.paper.PAPER`.
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
        """Add a paragraph to the section.

        Args:
            markdown: the paragraph, Markdown already (not escaped).
        """
        self.paragraphs.append(markdown.strip())

    def stand_in(self, lab: str, synthetic: str) -> None:
        """Name what in this synthetic study stands in for what the paper had in the lab.

        Args:
            lab: what the paper had (plain text).
            synthetic: what stands in for it here (plain text).
        """
        self.stand_ins.append({"lab": lab, "synthetic": synthetic})

    @stage("report")
    def table(self, name: str, df, caption: str = "", *, index: bool = False, digits: int = 3):
        """Write a table as ``tables/<name>.csv`` and ``tables/<name>.md`` for the report.

        Args:
            name: the file name (letters, digits, ``_``, ``-``, ``.``).
            df: a pandas DataFrame.
            caption: shown above the table ("": ``name``).
            index: write the DataFrame's index as a column.
            digits: decimals of floats in the Markdown (:func:`~.markdown.dataframe_markdown`).

        Returns:
            ``df``, unchanged.

        Raises:
            ValueError: ``name`` is empty or holds another character.
        """
        _check_name(name)
        tables = self.output_dir / "tables"
        csv_path, md_path = tables / f"{name}.csv", tables / f"{name}.md"
        with atomic_path(csv_path) as tmp:
            df.to_csv(tmp, index=index)
        atomic_write_text(md_path, dataframe_markdown(df, index=index, digits=digits) + "\n")
        self.tables.append(_Entry(name, caption, f"tables/{name}.md"))
        return df

    @stage("report")
    def figure(self, name: str, fig, caption: str = "", *, dpi: int = 110) -> Path:
        """Save a matplotlib figure as ``figures/<name>.png`` for the report.

        Args:
            name: the file name (letters, digits, ``_``, ``-``, ``.``).
            fig: a matplotlib figure.
            caption: shown under the figure ("": none).
            dpi: dots per inch of the PNG.

        Returns:
            The PNG's path.

        Raises:
            ValueError: ``name`` is empty or holds another character.
        """
        _check_name(name)
        path = self.output_dir / "figures" / f"{name}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
        self.figures.append(_Entry(name, caption, f"figures/{name}.png"))
        return path

    @stage("report")
    def image(self, name: str, rgb: np.ndarray, caption: str = "") -> Path:
        """Save an image (e.g. a pyvista screenshot) as ``figures/<name>.png`` for the report.

        Args:
            name: the file name (letters, digits, ``_``, ``-``, ``.``).
            rgb: ``(rows, cols, 3 | 4)`` uint8 RGB(A) pixels (alpha dropped).
            caption: shown under the figure ("": none).

        Returns:
            The PNG's path.

        Raises:
            ValueError: ``name`` is empty or holds another character, or ``rgb`` is not such an image.
            RuntimeError: OpenCV fails to encode the PNG.
        """
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

    @stage("report")
    def save(self) -> Path:
        """Write ``results.json`` (atomically), with the timings (``"total"`` since construction,
        unless timed already), the stage times since construction (``"stages"``:
        ``{stage: {"wall_s", "cpu_s", "calls"}}``, this save's own writing left out) and the
        provenance.

        Returns:
            The path of ``results.json``.
        """
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
            "stages": stage_delta(self._stages_before),
            "provenance": provenance(),
        }
        return atomic_write_json(self.output_dir / RESULTS_FILE, record)


def _check_name(name: str) -> None:
    if not name or not all(c.isalnum() or c in "_-." for c in name):
        raise ValueError(f"name must be letters, digits, '_', '-' or '.', got {name!r}")


def load_section(section_dir) -> dict:
    """Read the ``results.json`` of one section folder.

    Args:
        section_dir: the section's folder.

    Returns:
        The record :meth:`SectionWriter.save` wrote.

    Raises:
        OSError: there is no readable ``results.json``.
        ValueError: it is not JSON.
    """
    path = Path(section_dir) / RESULTS_FILE
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


# --- report assembly ---------------------------------------------------------------------------

REPORT_TITLE = "histostudy: X-ray C-arm guided automatic targeting for histotripsy, reproduced"
RUN_ANCHOR = "this-run"


def build_report(output_dir, run: dict | None = None) -> tuple[Path, Path]:
    """Assemble ``REPORT.md``, the sections' pages and the self-contained ``report.html`` in ``output_dir``.

    ``REPORT.md`` is the index: the profile's banner, the paper's key results beside their
    reproduction, the contents, this run's facts, every paper result with its reproduced twin and the
    software versions. Each finished section has its page, ``<section>/README.md``
    (:mod:`~.pages`), tables longer than :data:`~.pages.MAX_TABLE_ROWS` rows cut to their first rows
    there; a section whose notebook did not finish is named in the index with its status.
    ``report.html`` holds all of it on one page, every table whole and the figures embedded; the
    Markdown links its figures relatively.

    Args:
        output_dir: the run's folder, holding one folder per section.
        run: the pipeline's run record (profile, notebook order, timings, failure); None reads
            ``output_dir/run.json``.

    Returns:
        ``(REPORT.md path, report.html path)``.

    Raises:
        OSError: ``run`` is None and ``output_dir/run.json`` cannot be read.
        ValueError: that file is not JSON.
    """
    out = Path(output_dir)
    if run is None:
        with open(out / RUN_FILE, encoding="utf-8") as fh:
            run = json.load(fh)
    page = render_html(_whole_report(out, run), out, title=f"histostudy report ({run.get('profile', '')})")
    html_path = atomic_write_text(out / "report.html", page)
    index, pages = _report_pages(out, run)
    for name, text in pages.items():
        atomic_write_text(out / name / SECTION_PAGE, text)
    md_path = atomic_write_text(out / "REPORT.md", index)
    return md_path, html_path


def _report_parts(out: Path, run: dict, *, paged: bool) -> tuple[list[str], list[str], dict, list[str]]:
    """``(head, this_run, blocks, tail)``: the report's lines before the sections (title, banners,
    headline, contents), "This run", each section's ``(has_page, lines)`` (its page's form when
    ``paged``) and the lines after them (twins, software)."""
    sections, blocks, contents = {}, {}, []
    for nb in run.get("notebooks", []):
        name = nb["name"]
        section_dir = out / name
        # a section that did not finish in this run may hold an earlier run's results: not shown
        if nb.get("status", "ok") != "ok" or not (section_dir / RESULTS_FILE).is_file():
            title = name
            blocks[name] = (False, [f'<a id="{section_anchor(name)}"></a>', "", f"## {md_escape(name)}", "",
                                    f"*No results: status {md_escape(nb.get('status', 'not run'))}.*", ""])
        else:
            sections[name] = load_section(section_dir)
            title = sections[name].get("title", name)
            blocks[name] = (True, _section_markdown(name, sections[name], nb, section_dir, paged=paged))
        contents.append((title, section_anchor(name)))
    coverage = results_coverage(sections, run)
    versions = run.get("provenance", {}).get("versions", {})
    head = [f"# {md_escape(REPORT_TITLE)}", ""]
    head += profile_banner(run, _profile_description(run))
    head += _failure_banner(run.get("failure"))
    head += headline_markdown(coverage)
    head += contents_markdown([("This run", RUN_ANCHOR), *contents, (TWINS_HEADING, TWINS_ANCHOR),
                               *([("Software", SOFTWARE_ANCHOR)] if versions else [])])
    this_run = [f'<a id="{RUN_ANCHOR}"></a>', "", "## This run", "",
                "Wagner et al., *An X-ray C-arm Guided Automatic Targeting System for Histotripsy*, IEEE TBME "
                "70(2):592-602, 2023, reproduced on synthetic data: each section sets its numbers beside the "
                "paper's and names what stands in for the lab.", "", *run_facts(run)]
    tail = twins_markdown(coverage)
    if versions:
        tail += [f'<a id="{SOFTWARE_ANCHOR}"></a>', "", "## Software", "",
                 md_table(["package", "version"], versions.items()), ""]
    return head, this_run, blocks, tail


def _whole_report(out: Path, run: dict) -> str:
    """The whole report as one Markdown text, every section in it with its tables whole (report.html's)."""
    head, this_run, blocks, tail = _report_parts(out, run, paged=False)
    return "\n".join(head + this_run + [line for _, block in blocks.values() for line in block] + tail)


def _report_pages(out: Path, run: dict) -> tuple[str, dict[str, str]]:
    """``(index, pages)``: REPORT.md's text and each finished section's page text, links pointed at
    the pages."""
    head, this_run, blocks, tail = _report_parts(out, run, paged=True)
    # the index keeps each section's old anchors on its contents line, so that links made before
    # the report had pages still land beside the link to the page
    aliases = [f'<a id="{section_anchor(n)}"></a><a id="{stand_ins_anchor(n)}"></a>' for n, (has, _) in blocks.items()
               if has]
    index_lines = head + ["<!-- sections' earlier anchors -->", " ".join(aliases), ""] if aliases else list(head)
    index_lines += this_run + [line for has, block in blocks.values() if not has for line in block] + tail
    pages = {name: "\n".join(["[← the report](../REPORT.md)", "", *block]) for name, (has, block) in blocks.items()
             if has}
    page_of_anchor = {anchor: "REPORT.md" for anchor in anchors_of("\n".join(index_lines))}
    for name, text in pages.items():
        page_of_anchor.update({anchor: f"{name}/{SECTION_PAGE}" for anchor in anchors_of(text)})
    index = relink("\n".join(index_lines), "REPORT.md", page_of_anchor)
    return index, {name: relink(text, f"{name}/{SECTION_PAGE}", page_of_anchor) + "\n" for name, text in pages.items()}


def _profile_description(run: dict) -> str:
    source = run.get("profile_source") or run.get("profile")
    try:
        return load_profile(source).description if source else ""
    except (OSError, ValueError, KeyError):
        return ""


def _failure_banner(failure: dict | None) -> list[str]:
    if not failure:
        return []
    if failure.get("executed_notebook") is None:
        text = (f"**Run stopped:** notebook {md_code(failure['notebook'])} {md_escape(failure.get('error'))}; "
                "its kernel was stopped and its section is incomplete.")
    else:
        text = (f"**Run failed:** notebook {md_code(failure['notebook'])} at cell "
                f"{md_escape(failure.get('cell_index'))}: {md_escape(failure.get('error'))}. Its executed copy is "
                f"{md_code(failure.get('executed_notebook'))}.")
    # the comment keeps Python-Markdown from merging this quote into the profile's banner above it
    return ["<!-- run failure -->", "", "> [!CAUTION]", f"> {text}", ""]


def _section_markdown(name: str, res: dict, nb: dict, section_dir: Path, *, paged: bool) -> list[str]:
    """A section's Markdown: on its own page (``paged``: figures linked from the section's folder,
    long tables cut) or in the whole report (figures linked from the run's folder, tables whole)."""
    lines = [f'<a id="{section_anchor(name)}"></a>', "", f"## {md_escape(res.get('title', name))}", ""]
    lines += [_section_facts(name, res, nb), ""]
    for para in res.get("text", []):
        lines += [para, ""]
    comps = res.get("comparisons", [])
    if comps:
        rows = [[c["label"], c["ours_text"], c["paper_text"], _versus_paper(c), c.get("paper_where", ""),
                 c.get("note", "")] for c in comps]
        lines += [md_table(["Quantity", "This study", "Paper", "Difference", "Source", "Note"], rows), ""]
    for t in res.get("tables", []):
        text = _read_text(section_dir / t["path"])
        csv = section_dir / Path(t["path"]).with_suffix(".csv")
        if text is None and csv.is_file():  # a published long table keeps its CSV only
            text = dataframe_markdown(pd.read_csv(csv))
        if text is not None and paged:
            text = shorten_table(text, str(Path(t["path"]).with_suffix(".csv").as_posix()))
        missing = f"(table {md_code(t['path'])} missing)"
        lines += [f"**{md_escape(t['caption'] or t['name'])}**", "", text or missing, ""]
    folder = "" if paged else f"{name}/"
    for f in res.get("figures", []):
        lines += [f"![{md_escape(f['caption'] or f['name'])}]({folder}{f['path']})", ""]
        if f["caption"]:
            lines += [f"*{md_escape(f['caption'])}*", ""]
    causes = section_causes(comps)
    if causes:
        lines += ["Why its numbers differ from the paper's:", ""]
        lines += [f'- <a id="{why_anchor(name, cause.slug)}"></a>**{md_escape(cause.title)}** '
                  f'({md_escape(", ".join(labels))}): {as_sentence(cause.reason)}' for cause, labels in causes]
        lines.append("")
    stand_ins = res.get("stand_ins", [])
    if stand_ins:
        lines += [f'<a id="{stand_ins_anchor(name)}"></a>', "", "What stands in for the lab:", ""]
        lines += [f"- {md_escape(s['lab'])} → {md_escape(s['synthetic'])}" for s in stand_ins]
        lines.append("")
    timings = res.get("timings_s", {})
    if timings:
        lines += ["Timings: " + md_escape(", ".join(f"{k} {v:.2f} s" for k, v in timings.items())), ""]
    return lines


def _section_facts(name: str, res: dict, nb: dict) -> str:
    """The section's first line: notebook, executed copy, wall and CPU time, and the commit and CPU
    that made it (a kept section may come from an earlier commit or another machine)."""
    seconds, cpu = nb.get("seconds"), nb.get("cpu_seconds")
    prov = res.get("provenance", {})
    text = f"*Notebook {md_code(name)}, executed copy {md_code(f'notebooks/{name}.ipynb')}"
    if isinstance(seconds, (int, float)):
        text += f", {seconds:.1f} s" + (f" ({cpu:.0f} CPU-s)" if isinstance(cpu, (int, float)) else "")
    if prov.get("git_commit"):
        commit = str(prov["git_commit"])
        text += f"; commit {md_code(commit[:12] + ('-dirty' if commit.endswith('-dirty') else ''))}"
    cpu_model = (prov.get("machine") or {}).get("cpu_model")
    if cpu_model:
        text += f" on {md_escape(cpu_model)}, {md_escape(prov['machine'].get('cpus'))} cores"
    renderer = SPLAT_RENDERERS.get(str((res.get("parameters") or {}).get("splat_device")))
    if renderer:
        text += f"; frames splatted by {renderer}"
    return text + ("; kept from an earlier run (same content key)" if nb.get("kept") else "") + ".*"


def _versus_paper(comparison: dict) -> str:
    """The section table's "Difference" cell: ``"+23.57 deg, ⚠ far off (33 SD)"``, or "—"."""
    value = PAPER.get(comparison.get("paper_key") or "")
    if value is None:
        return "—"
    agreement = judge(comparison, value, twin=PAPER.get(value.twin))
    if agreement.status == NOT_JUDGED:
        return "—"
    flag = "⚠ " if agreement.status == FAR_OFF else ""
    prefix = "" if agreement.difference is None else f"{agreement.difference_text()}, "
    key = comparison.get("paper_key") or comparison.get("key") or ""
    cause = known_cause(key, comparison.get("ours"), value.mean, agreement, row_key=comparison.get("key"))
    if cause is not None and cause.better:
        return f"{prefix}{BETTER}{agreement.summary()[len(agreement.status):]}"
    return f"{prefix}{flag}{agreement.summary()}"


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8").strip()
    except OSError:
        return None


def write_run_record(output_dir, run: dict) -> Path:
    """Write the pipeline's run record ``run.json`` (atomically).

    Args:
        output_dir: the run's folder.
        run: the record.

    Returns:
        The path of ``run.json``.
    """
    return atomic_write_json(Path(output_dir) / RUN_FILE, run)
