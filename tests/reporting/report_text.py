"""The whole Markdown report of a run's folder, as a reader follows its links: ``REPORT.md`` (the
index), then each section's page."""

from pathlib import Path


def report_text(folder) -> str:
    """``REPORT.md`` and every ``<section>/README.md`` of ``folder``, in the index's order."""
    folder = Path(folder)
    index = (folder / "REPORT.md").read_text(encoding="utf-8")
    pages = sorted(folder.glob("*/README.md"), key=lambda p: index.find(f"]({p.parent.name}/README.md"))
    return "\n".join([index, *(p.read_text(encoding="utf-8") for p in pages)])
