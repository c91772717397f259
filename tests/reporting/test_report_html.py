"""report.html stands alone and is well formed: checked with the standard library's HTML parser
(balanced tags, every image a data URI, every table in a scrolling div, no Markdown table left as
text, every in-page link resolved)."""

import base64
import re
from html.parser import HTMLParser

import pandas as pd

from histostudy.reporting import build_report
from histostudy.reporting.report_html import render_html

VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}
RAW_TABLE_LINE = re.compile(r"^\s*\|.*\|\s*$|\|\s*:?-{3,}")


class PageCheck(HTMLParser):
    """Collects what a self-contained report page must satisfy; ``problems`` lists what it does not."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.stack, self.problems, self.images, self.ids, self.links = [], [], [], set(), []
        self.tables, self.meta = [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            if attrs["id"] in self.ids:
                self.problems.append(f"duplicate id {attrs['id']!r}")
            self.ids.add(attrs["id"])
        if tag == "a" and attrs.get("href", "").startswith("#"):
            self.links.append(attrs["href"][1:])
        if tag == "img":
            self.images.append(attrs.get("src", ""))
        if tag == "meta":
            self.meta.append(attrs)
        if tag == "table":
            parent = self.stack[-1] if self.stack else ("", {})
            wrapped = parent[0] == "div" and parent[1].get("class") == "table-scroll"
            self.tables.append((attrs.get("class", ""), wrapped))
        if tag not in VOID:
            self.stack.append((tag, attrs))

    def handle_startendtag(self, tag, attrs):
        self.handle_starttag(tag, attrs)
        if tag not in VOID:
            self.stack.pop()

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1][0] != tag:
            self.problems.append(f"</{tag}> closes {self.stack[-1][0] if self.stack else 'nothing'}")
            return
        self.stack.pop()

    def handle_data(self, data):
        if any(t in ("style", "script", "code", "pre") for t, _ in self.stack):
            return
        for line in data.splitlines():
            if RAW_TABLE_LINE.search(line):
                self.problems.append(f"Markdown table left as text: {line.strip()[:60]!r}")

    def check(self, page: str) -> "PageCheck":
        self.feed(page)
        self.close()
        if self.stack:
            self.problems.append(f"unclosed: {[t for t, _ in self.stack]}")
        self.problems += [f"link to missing #{a}" for a in self.links if a not in self.ids]
        self.problems += [f"image not embedded: {src[:40]!r}" for src in self.images if not src.startswith("data:")]
        self.problems += ["table outside a scrolling div" for _, wrapped in self.tables if not wrapped]
        return self


def _demo_report(folder):
    folder.section("01_demo", compare=[dict(key="model.radius_mm", label="Cap radius", ours=138.7, unit="mm")],
                   tables=[("variants", folder.wide_table(), "Centre error per mode | map kind (mm)"),
                           ("small", pd.DataFrame({"a": [1]}), "Small")],
                   image=True, stand_ins=[("lab frames", "synthetic <frames> & labels")], text=["Some *markdown*."])
    folder.section("06_lab", compare=[dict(key="lab.thing", label="Lab-only value", ours=2.0, paper_key="")])
    failure = {"notebook": "07_broken", "cell_index": 3, "error": "ValueError: a | b < c",
               "executed_notebook": "e.ipynb"}
    run = folder.run(extra=["07_broken"], statuses={"07_broken": "failed"}, failure=failure)
    return build_report(folder.root, run)


def test_report_page_is_self_contained_and_well_formed(folder):
    md_path, html_path = _demo_report(folder)
    page = html_path.read_text(encoding="utf-8")
    check = PageCheck().check(page)
    assert check.problems == []
    assert {"name": "viewport", "content": "width=device-width, initial-scale=1"} in check.meta
    assert len(check.images) == 1
    png = base64.b64decode(check.images[0].removeprefix("data:image/png;base64,"))
    assert png == (folder.root / "01_demo/figures/shot.png").read_bytes()
    # the headline, sections' comparisons and small tables become cards on a phone; the wide one scrolls
    classes = [cls for cls, _ in check.tables]
    assert classes.count("") == 2 and "cards" in classes  # the wide variants table and the twins table
    assert {"01_demo", "01_demo-stand-ins", "06_lab", "07_broken", "twins", "contents", "software"} <= check.ids
    assert 'class="alert alert-warning"' in page and 'class="alert alert-caution"' in page
    assert "centre |depth|" in page and "a &lt; b &amp; c" in page and "ValueError: a | b &lt; c" in page
    assert "[!WARNING]" not in page
    # the section's page keeps the figure as a relative link for GitHub
    assert "![A red figure](figures/shot.png)" in (folder.root / "01_demo" / "README.md").read_text(encoding="utf-8")


def test_css_keeps_the_page_within_a_phone(folder):
    page = _demo_report(folder)[1].read_text(encoding="utf-8")
    style = page[page.index("<style>"):page.index("</style>")]
    assert "max-width:1100px" in style and "img{max-width:100%" in style and ".table-scroll{overflow-x:auto" in style
    assert "@media (max-width:600px)" in style


def test_missing_or_outside_figures_are_named_not_linked(tmp_path):
    (tmp_path / "inside").mkdir()
    (tmp_path / "outside.png").write_bytes(b"\x89PNG")
    page = render_html("![gone](inside/nope.png)\n\n![out](../outside.png)\n\n![web](http://x/y.png)",
                       tmp_path / "inside", title="a <title>")
    check = PageCheck().check(page)
    assert check.images == [] and check.problems == []
    assert page.count('class="missing"') == 3 and "inside/nope.png" not in page.split("<body>")[0]
    assert "<title>a &lt;title&gt;</title>" in page
