"""The one escaping function and the tables built on it: what goes in as text comes out as the same
text, in the same cell, once rendered as report.html renders it."""

import html
import re
from html.parser import HTMLParser

import numpy as np
import pandas as pd
import pytest

from histostudy.reporting.markdown import Markdown, dataframe_markdown, md_code, md_escape, md_link, md_table
from histostudy.reporting.report_html import render_html

TRICKY = ["a | b", "x < y & z > w", "*not emphasis*", "snake_case_name", "_not emphasis_", "__init__ a_b_ _c",
          "in_channels': 1, 'n_classes", "`tick`", "[not](a link)", "back\\slash",
          "&amp; stays literal", "<b>no tag</b>", "2 * 3 * 4", "line one\nline two", "± 0.5 mm, ≈ 240 x 170", ""]


class _Cells(HTMLParser):
    """The text of every th/td of a rendered table, row by row."""

    def __init__(self):
        super().__init__()
        self.rows, self._cell = [], None

    def handle_starttag(self, tag, attrs):
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self.rows[-1].append(self._cell)
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data


def _body(md_text, tmp_path):
    page = render_html(md_text, tmp_path, title="t")
    return page[page.index("<body>") + len("<body>"):page.index("</body>")].strip()


def _render_cells(md_text, tmp_path):
    parser = _Cells()
    parser.feed(_body(md_text, tmp_path))
    return parser.rows


@pytest.mark.parametrize("text", TRICKY)
def test_escaped_text_renders_as_itself(text, tmp_path):
    rendered = _body(md_escape(text), tmp_path)
    plain = html.unescape(re.sub(r"^<p>|</p>$", "", rendered))
    assert plain == " ".join(text.splitlines())
    assert "<em>" not in rendered and "<b>" not in rendered and "<a " not in rendered and "<code>" not in rendered


def test_table_keeps_every_cell_in_its_column(tmp_path):
    header = ["centre |depth|", "a < b", "plain"]
    rows = [[t, t, Markdown("**bold**")] for t in TRICKY]
    cells = _render_cells(md_table(header, rows, ["l", "r", "l"]), tmp_path)
    assert cells[0] == header
    assert all(len(r) == 3 for r in cells)
    assert [r[0] for r in cells[1:]] == [" ".join(t.splitlines()) for t in TRICKY]


def test_markdown_passes_through_and_helpers():
    assert md_escape("06_your_data") == "06_your_data"  # an underscore inside a word cannot start emphasis
    assert md_escape("_x_") == "\\_x\\_"
    assert md_escape(Markdown("[x](#y)")) == "[x](#y)"
    assert md_escape(None) == ""
    assert md_code("table1.screws.precision") == "`table1.screws.precision`"
    assert md_link("A | b", "02_seg") == "[A \\| b](#02_seg)"
    with pytest.raises(ValueError, match="code span"):
        md_code("a`b")
    with pytest.raises(ValueError, match="anchor"):
        md_link("x", "has space")


def test_table_errors_name_the_argument():
    with pytest.raises(ValueError, match=r"rows\[1\] has 1 cells, the header 2"):
        md_table(["a", "b"], [["1", "2"], ["3"]])
    with pytest.raises(ValueError, match="align"):
        md_table(["a", "b"], [], ["l"])
    with pytest.raises(ValueError, match="align"):
        md_table(["a"], [], ["c"])


def test_dataframe_markdown_formats_and_aligns(tmp_path):
    df = pd.DataFrame({"class |x|": ["a", "b"], "n": np.array([1, 2], dtype=np.int64), "v": [0.12345, np.nan],
                       "ok": [True, False], "na": pd.array([1, None], dtype="Int64")})
    text = dataframe_markdown(df, digits=2)
    lines = text.splitlines()
    assert lines[1] == "|:---|---:|---:|:---|---:|"
    assert _render_cells(text, tmp_path) == [["class |x|", "n", "v", "ok", "na"], ["a", "1", "0.12", "True", "1"],
                                   ["b", "2", "n/a", "False", "n/a"]]
    indexed = dataframe_markdown(df.set_index("class |x|"), index=True, digits=1)
    assert _render_cells(indexed, tmp_path)[0][0] == "class |x|"
