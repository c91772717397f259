"""``report.html``: the report's Markdown as one self-contained page (figures embedded, tables that
scroll, GitHub alerts as banners), readable from a phone to a desktop (docs/report.md, "The HTML
page")."""

from __future__ import annotations

import base64
import html
import mimetypes
import xml.etree.ElementTree as etree
from pathlib import Path

import markdown as markdown_lib
from markdown.extensions import Extension
from markdown.treeprocessors import Treeprocessor

__all__ = ["CARD_COLUMNS", "render_html"]

_CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;max-width:1100px;margin:0 auto;
padding:.5em 1em 3em;line-height:1.45;color:#222;overflow-wrap:break-word}
h1{font-size:1.55em;line-height:1.25}
h2{font-size:1.3em;margin-top:1.8em;padding-bottom:.2em;border-bottom:1px solid #ddd}
.table-scroll{overflow-x:auto;margin:.8em 0;max-width:100%}
table{border-collapse:collapse;font-size:.9em}
th,td{border:1px solid #ccc;padding:.3em .55em;text-align:left;vertical-align:top}
th{background:#f3f3f3}
img{max-width:100%;height:auto;border:1px solid #ddd;margin:.4em 0}
code{background:#f4f4f4;padding:0 .2em;overflow-wrap:anywhere}
blockquote{margin:1em 0;padding:.6em .9em;border-left:5px solid #999;background:#f7f7f7}
blockquote p{margin:.3em 0}
.alert-warning{border-color:#d97706;background:#fff6e0}
.alert-caution{border-color:#c00;background:#fee}
.alert-note{border-color:#2563eb;background:#eef4ff}
.missing{color:#b00;font-style:italic}
@media (max-width:600px){body{padding:.3em .6em 2em;font-size:15px}table{font-size:.85em}h1{font-size:1.3em}
table.cards,table.cards tbody,table.cards tr,table.cards td{display:block;width:100%}
table.cards thead{display:none}
table.cards tr{border:1px solid #ccc;border-radius:4px;margin:.5em 0;padding:.3em .5em}
table.cards td{border:none;padding:.1em 0;text-align:left!important}
table.cards td:empty{display:none}
table.cards td:first-child{font-weight:600}
table.cards td:not(:first-child)::before{content:attr(data-label) ": ";color:#555}}
"""
#: Tables with at most this many columns become cards below 600 px.
CARD_COLUMNS = 6

_ALERTS = ("NOTE", "WARNING", "CAUTION")


def render_html(markdown_text: str, base_dir, *, title: str) -> str:
    """The HTML page of ``markdown_text``, with the images it links embedded from ``base_dir``.

    Args:
        markdown_text: the report's Markdown (``REPORT.md``).
        base_dir: the folder the Markdown's image paths are relative to (the report's output folder).
        title: the page title (plain text).

    An image whose file is missing, lies outside ``base_dir`` or is not a local file is replaced by
    a visible note naming it, so the page never refers to a file beside it.
    """
    converter = markdown_lib.Markdown(extensions=["tables", "fenced_code", _SelfContained(Path(base_dir))])
    body = converter.convert(markdown_text)
    return ('<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n")


def _data_uri(path: Path) -> str:
    mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


class _SelfContained(Extension):
    """Reads ``\\|`` as an escaped ``|`` and registers :class:`_Embed` after the inline processing."""

    def __init__(self, base_dir: Path):
        super().__init__()
        self.base_dir = base_dir

    def extendMarkdown(self, md):  # noqa: N802 - Python-Markdown's name
        # md_escape puts a backslash before every pipe; GitHub reads that as an escape everywhere,
        # Python-Markdown only inside tables unless told
        md.ESCAPED_CHARS = [*md.ESCAPED_CHARS, "|"]
        md.treeprocessors.register(_Embed(md, self.base_dir), "histostudy_embed", 0)


class _Embed(Treeprocessor):
    """Embeds images, wraps tables in a scrolling div and styles GitHub alerts."""

    def __init__(self, md, base_dir: Path):
        super().__init__(md)
        self.base_dir = base_dir.resolve()

    def run(self, root):
        for parent in list(root.iter()):
            for index, child in enumerate(list(parent)):
                if child.tag == "table":
                    self._wrap(parent, index, child)
                elif child.tag == "img":
                    self._embed(parent, index, child)
                elif child.tag == "blockquote":
                    self._alert(child)
        return None

    @staticmethod
    def _wrap(parent, index, table):
        header = [" ".join("".join(th.itertext()).split()) for th in table.iter("th")]
        for tr in table.iter("tr"):
            for label, td in zip(header, tr.findall("td")):
                td.set("data-label", label)
        if len(header) <= CARD_COLUMNS:
            table.set("class", "cards")
        wrapper = etree.Element("div", {"class": "table-scroll"})
        wrapper.tail, table.tail = table.tail, None
        parent.remove(table)
        wrapper.append(table)
        parent.insert(index, wrapper)

    def _embed(self, parent, index, img):
        src = img.get("src", "")
        if src.startswith("data:"):
            return
        path = (self.base_dir / src).resolve() if "://" not in src else None
        if path is not None and path.is_relative_to(self.base_dir) and path.is_file():
            img.set("src", _data_uri(path))
            return
        note = etree.Element("span", {"class": "missing"})
        note.text = f"[figure not embedded: {src} is missing or not a file in the report's folder]"
        note.tail = img.tail
        parent.remove(img)
        parent.insert(index, note)

    @staticmethod
    def _alert(quote):
        first = next(iter(quote), None)
        text = (first.text or "") if first is not None and first.tag == "p" else ""
        for kind in _ALERTS:
            marker = f"[!{kind}]"
            if text.startswith(marker):
                first.text = text[len(marker):].lstrip()
                quote.set("class", f"alert alert-{kind.lower()}")
                return
