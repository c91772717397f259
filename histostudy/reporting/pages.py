"""The report in pages (docs/report.md, "The report's pages"): ``REPORT.md`` is a short index and each
section has a page of its own, ``<section>/README.md`` (GitHub shows it when the folder is opened).
Tables longer than :data:`MAX_TABLE_ROWS` rows are cut there (the whole table stays in its CSV and in
``report.html``), and every link to an anchor is pointed at the page that holds it."""

from __future__ import annotations

import os
import re

__all__ = ["MAX_TABLE_ROWS", "SECTION_PAGE", "anchors_of", "relink", "shorten_table"]

#: The name of a section's page in its folder.
SECTION_PAGE = "README.md"

#: Tables with more rows than this are cut on a page (their first :data:`_KEPT_ROWS` rows shown).
MAX_TABLE_ROWS = 40
_KEPT_ROWS = 20

_ANCHOR = re.compile(r'<a id="([^"]+)"></a>')
_ANCHOR_LINK = re.compile(r"\]\(#([A-Za-z0-9_.-]+)\)")


def anchors_of(markdown: str) -> list[str]:
    """The ids the page's ``<a id="..."></a>`` tags define, in order."""
    return _ANCHOR.findall(markdown)


def relink(markdown: str, page: str, page_of_anchor: dict[str, str]) -> str:
    """``markdown`` of ``page`` with each ``](#anchor)`` pointed at the page that holds the anchor.

    Args:
        markdown: the page's text.
        page: its path relative to the report's folder (``"REPORT.md"``, ``"02_segmentation/README.md"``).
        page_of_anchor: anchor -> the path (relative to the report's folder) of the page holding it.

    Returns:
        The text with links to anchors on other pages made relative paths to them (``../REPORT.md#twins``);
        links to this page's anchors and to unknown anchors are left as they are.
    """
    here = os.path.dirname(page) or "."

    def point(match: re.Match) -> str:
        anchor = match.group(1)
        target = page_of_anchor.get(anchor)
        if target is None or target == page:
            return match.group(0)
        return f"]({os.path.relpath(target, here).replace(os.sep, '/')}#{anchor})"

    return _ANCHOR_LINK.sub(point, markdown)


def shorten_table(table_md: str, csv_link: str) -> str:
    """A Markdown table cut to its first rows when it has more than :data:`MAX_TABLE_ROWS`.

    Args:
        table_md: the table (header, separator and rows, one line each).
        csv_link: the relative link of its whole CSV.

    Returns:
        ``table_md`` itself, or its header and first rows followed by a line naming how many rows
        were left out and where the whole table is.
    """
    lines = table_md.strip().splitlines()
    rows = len(lines) - 2
    if rows <= MAX_TABLE_ROWS:
        return table_md
    kept = "\n".join(lines[:2 + _KEPT_ROWS])
    return (f"{kept}\n\n*{rows - _KEPT_ROWS} more rows of {rows}: the whole table is [{csv_link.rsplit('/', 1)[-1]}]"
            f"({csv_link}) and in report.html.*")
