"""Every result of the paper (:data:`RESULT_KEYS`, 77 numbers) and its reproduced twin: which section
reproduces it, the value, the difference and the status, or why this run has none (docs/report.md,
"The paper's results and their twins")."""

from __future__ import annotations

from .agreement import AGREES, FAR_OFF, NOT_JUDGED, judge
from .expected import BETTER, BUDGET_SECTION, known_cause
from .markdown import Markdown, md_code, md_escape, md_link, md_table
from .paper import PAPER

__all__ = ["RESULT_KEYS", "TWINS_HEADING", "TWINS_ANCHOR", "results_coverage", "section_anchor", "stand_ins_anchor",
           "status_markdown", "twins_markdown", "why_anchor"]

TWINS_HEADING = "The paper's results and their reproduced twins"
TWINS_ANCHOR = "twins"

#: The paper's results: the keys of PAPER from §III, the tables and the abstract, in PAPER's order.
RESULT_KEYS = tuple(k for k, v in PAPER.items() if any(tag in v.where for tag in ("§III", "Table", "abstract")))

#: The notebook (its number) whose section reports each group of paper keys; used only to say why
#: a result is missing from a run.
_NOTEBOOK_OF_GROUP = {"table1": "02", "seg": "02", "angles": "03", "table2": "04", "pose": "04", "targeting": "05"}


def section_anchor(name: str) -> str:
    """The report's anchor (HTML id) of section ``name`` (its notebook stem)."""
    return name


def stand_ins_anchor(name: str) -> str:
    """The anchor of section ``name``'s list of what stands in for the lab."""
    return f"{name}-stand-ins"


def why_anchor(name: str, slug: str) -> str:
    """The anchor of the sentence in section ``name`` that explains a difference (a
    :class:`~.expected.KnownCause`'s ``slug``)."""
    return f"{name}-why-{slug}"


def results_coverage(sections: dict[str, dict], run: dict | None = None) -> list[dict]:
    """One row per paper result (:data:`RESULT_KEYS`), in PAPER's order.

    Args:
        sections: section name -> its loaded results (``load_section``), in run order.
        run: the pipeline's run record; its notebooks' statuses say why a result is missing.

    Each row holds ``key``, ``label``, ``paper_text``, ``where``; ``sections`` (every section with a
    comparison against the key or its twin); ``section`` and ``comparison`` (the twin used, or
    None); ``via`` (the Table II key it was found through, or ""); ``agreement``
    (:class:`~histostudy.reporting.agreement.Agreement`, or None); ``stand_ins`` (the twin's
    section's, see ``SectionWriter.stand_in``); ``reason`` (Markdown: why there is no twin, "" when
    there is one); ``budget_in_run`` (whether the error budget's section, which adds the lab's error
    sources back, is in the run).
    """
    rows = []
    for key in RESULT_KEYS:
        value = PAPER[key]
        found, via = _comparisons(sections, key), ""
        if not found and value.twin:
            found, via = _comparisons(sections, value.twin), value.twin
        section, comparison = _primary(found, via or key)
        rows.append({
            "key": key, "label": value.label, "paper_text": value.format(), "where": value.where,
            "sections": list(dict.fromkeys(name for name, _ in found)),
            "section": section, "comparison": comparison, "via": via,
            "agreement": judge(comparison, value, twin=PAPER.get(value.twin)) if comparison else None,
            "stand_ins": sections[section].get("stand_ins", []) if section else [],
            "reason": "" if comparison else _reason(key, sections, run),
            "budget_in_run": BUDGET_SECTION in sections,
        })
    return rows


def _comparisons(sections: dict[str, dict], key: str) -> list[tuple[str, dict]]:
    return [(name, c) for name, res in sections.items() for c in res.get("comparisons", [])
            if c.get("paper_key", c.get("key")) == key]


def _primary(found: list[tuple[str, dict]], key: str) -> tuple[str | None, dict | None]:
    for name, c in found:
        if c.get("key") == key:
            return name, c
    return found[0] if found else (None, None)


def _reason(key: str, sections: dict[str, dict], run: dict | None) -> Markdown:
    needs = PAPER[key].needs
    if needs:
        needed_key, why = needs
        section, needed = _primary(_comparisons(sections, needed_key), needed_key)
        if section is not None and needed is not None:
            return Markdown(f"not computed in {md_link(section, section_anchor(section))}: {md_escape(why)}; "
                            f"this run's {md_escape(PAPER[needed_key].label)}: {md_escape(needed['ours_text'])}")
    number = _NOTEBOOK_OF_GROUP.get(key.split(".")[0])
    notebooks = (run or {}).get("notebooks") or [{"name": n, "status": "ok"} for n in sections]
    if number is None:
        return Markdown("no section of this run compares it")
    entry = next((nb for nb in notebooks if nb["name"][:2] == number), None)
    if entry is None:
        return Markdown(f"not in this run: notebook {number} was not run")
    if entry.get("status", "ok") != "ok" or entry["name"] not in sections:
        return Markdown(f"not in this run: notebook {md_code(entry['name'])} did not finish "
                        f"({md_escape(entry.get('status', 'no results'))})")
    return Markdown(f"{md_link(entry['name'], section_anchor(entry['name']))} records no comparison for it")


def status_markdown(row: dict) -> Markdown:
    """A coverage row's status for a table cell: the agreement in bold (far off flagged with ⚠);
    where the number differs for a known cause (:func:`~.expected.known_cause`), "better than the
    paper" with its reason, or a link to the section's sentence on the cause and then to its
    stand-ins (why); where it differs otherwise or was not judged, a link to the stand-ins; the
    reason where there is no twin."""
    agreement = row["agreement"]
    if agreement is None:
        return Markdown(row["reason"])
    summary, status = agreement.summary(), agreement.status
    name = row["section"]
    cause = known_cause(row["key"], row["comparison"]["ours"], PAPER[row["key"]].mean, agreement,
                        row_key=row["comparison"].get("key"))
    if cause is not None and cause.better:  # summary() starts with the status
        budget = f"; {md_link('the error budget adds them', BUDGET_SECTION)}" if row.get("budget_in_run") else ""
        return Markdown(f"**{BETTER}**{md_escape(summary[len(status):])}: {md_escape(cause.reason)}{budget}")
    if status == NOT_JUDGED:
        text = md_escape(summary)
    else:
        text = Markdown(f"{'⚠ ' if status == FAR_OFF else ''}**{status}**{md_escape(summary[len(status):])}")
    if status == AGREES:
        return text
    number = name[:2] if name[:2].isdigit() else name
    stand_ins = md_link(f"{number} stand-ins", stand_ins_anchor(name)) if row["stand_ins"] else None
    if cause is not None:
        return Markdown(f"{text}; why: {md_link(cause.title, why_anchor(name, cause.slug))}"
                        + (f", {stand_ins}" if stand_ins else ""))
    if status != NOT_JUDGED and stand_ins:
        return Markdown(f"{text}; why: {stand_ins}")
    return Markdown(f"{text}; see {md_link(number, section_anchor(name))}")


def twins_markdown(coverage: list[dict]) -> list[str]:
    """The report's closing table, as Markdown lines under one heading: every paper result with
    the paper's value, the reproduced value, the difference, the status and the section."""
    rows = []
    for row in coverage:
        c, a = row["comparison"], row["agreement"]
        where = ""
        if row["section"]:
            where = md_link(row["section"], section_anchor(row["section"]))
            if row["via"]:
                where = Markdown(f"{where}, as Table II's {md_escape(PAPER[row['via']].label)}")
        rows.append([f"{row['label']} ({row['where']})", row["paper_text"], c["ours_text"] if c else "—",
                     a.difference_text() if a else "—", status_markdown(row), where, md_code(row["key"])])
    n = sum(1 for row in coverage if row["comparison"])
    count = (f"all **{n} of {len(coverage)}** have a twin in this run" if n == len(coverage) else
             f"**{n} of {len(coverage)}** have a twin in this run; each of the others says why not")
    return [f'<a id="{TWINS_ANCHOR}"></a>', "", f"## {md_escape(TWINS_HEADING)}", "",
            f"Every number of the paper's §III (Tables I and II, the statistics in the text, the targeting "
            f"paragraph) and the abstract beside its reproduction: {count}.", "",
            md_table(["Paper result", "Paper", "This run", "Difference", "Status", "Reproduced in", "Key"], rows),
            ""]
