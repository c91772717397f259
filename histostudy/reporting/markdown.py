"""Markdown for the report: the one escaping function (:func:`md_escape`) and the tables, links and
code built on it; text that is Markdown already is wrapped in :class:`Markdown` and passes through
unchanged (docs/report.md, "Text and escaping")."""

from __future__ import annotations

import numbers
import re

__all__ = ["Markdown", "dataframe_markdown", "md_code", "md_escape", "md_link", "md_table"]

# The characters inline Markdown (CommonMark + GitHub tables) can read as syntax, and what each
# becomes. The backslash comes first so that the escapes added for the others are not escaped again.
_ESCAPES = (("\\", "\\\\"), ("&", "&amp;"), ("<", "&lt;"), ("|", "\\|"), ("*", "\\*"), ("`", "\\`"),
            ("[", "\\["), ("]", "\\]"))
# An underscore opens or closes emphasis only beside a non-alphanumeric character: one inside a word
# (06_your_data, in_channels) stays as it is, so names read the same in REPORT.md as rendered.
_EDGE_UNDERSCORE = re.compile(r"(?<![^\W_])_|_(?![^\W_])")


class Markdown(str):
    """A string that is Markdown already: :func:`md_table` and :func:`md_escape` leave it as it is."""


def md_escape(text) -> Markdown:
    """Plain ``text`` (anything; ``str()`` is taken) as inline Markdown that shows it literally.

    Escapes ``\\ & < | * ` [ ]``, and ``_`` where it touches a non-alphanumeric character (inside a
    word it cannot start emphasis), and folds line breaks into spaces (a table row is one line).
    A :class:`Markdown` passes through with its line breaks folded. ``None`` gives ``""``.
    """
    if text is None:
        return Markdown("")
    if isinstance(text, Markdown):
        return Markdown(" ".join(text.splitlines()))
    out = " ".join(str(text).splitlines())
    for char, escaped in _ESCAPES:
        out = out.replace(char, escaped)
    return Markdown(_EDGE_UNDERSCORE.sub(r"\\_", out))


def md_code(text) -> Markdown:
    """``text`` as an inline code span (a key, a file name); backticks in it are refused."""
    text = str(text)
    if "`" in text or "\n" in text:
        raise ValueError(f"text of a code span must hold no backtick or line break, got {text!r}")
    return Markdown(f"`{text}`")


def md_link(text, anchor: str) -> Markdown:
    """A link to ``#anchor`` (an id in the same report) showing the plain ``text``."""
    if not anchor or not all(c.isalnum() or c in "_-." for c in anchor):
        raise ValueError(f"anchor must be letters, digits, '_', '-' or '.', got {anchor!r}")
    return Markdown(f"[{md_escape(text)}](#{anchor})")


def md_table(header, rows, align=None) -> str:
    """A GitHub-flavoured Markdown table.

    Args:
        header: the column names (plain text or :class:`Markdown`).
        rows: one sequence of cells per row, as many as ``header``; plain cells are escaped with
            :func:`md_escape`, :class:`Markdown` cells pass through.
        align: per column ``"l"`` or ``"r"`` (default all ``"l"``).
    """
    header = list(header)
    align = list(align or ["l"] * len(header))
    if len(align) != len(header):
        raise ValueError(f"align must give one of 'l'/'r' per column ({len(header)}), got {align!r}")
    if any(a not in ("l", "r") for a in align):
        raise ValueError(f"align must hold only 'l' or 'r', got {align!r}")
    lines = ["| " + " | ".join(md_escape(h) for h in header) + " |",
             "|" + "|".join(":---" if a == "l" else "---:" for a in align) + "|"]
    for i, row in enumerate(rows):
        row = list(row)
        if len(row) != len(header):
            raise ValueError(f"rows[{i}] has {len(row)} cells, the header {len(header)}: {row!r}")
        lines.append("| " + " | ".join(md_escape(c) for c in row) + " |")
    return "\n".join(lines)


def dataframe_markdown(df, *, index: bool = False, digits: int = 3) -> str:
    """A pandas DataFrame as a :func:`md_table`: floats with ``digits`` decimals, missing values as
    ``"n/a"``, numeric columns right-aligned; the index as the first column when ``index``."""
    if index:
        df = df.reset_index()
    columns = [str(c) if not isinstance(c, tuple) else " / ".join(map(str, c)) for c in df.columns]
    numeric = [df[c].dtype.kind in "iuf" for c in df.columns]
    rows = [[_cell(v, digits) for v in record] for record in df.itertuples(index=False, name=None)]
    return md_table(columns, rows, ["r" if n else "l" for n in numeric])


def _cell(value, digits: int) -> str:
    import pandas as pd

    if pd.api.types.is_scalar(value) and pd.isna(value):
        return "n/a"
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return str(bool(value))
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return f"{float(value):.{digits}f}"
    return str(value)
