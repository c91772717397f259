"""The documentation site in a real browser: headless Chromium's screenshots of the home page, one
API page and one notebook page of a built site (``make docs``), each checked not to be blank and to
show what it should (docs/site.md).

Usage::

    python scripts/docs_screenshots.py [--site docs/_build/html] [--out docs/img/site]

Exits 1 where a page is missing, a screenshot fails or comes out (nearly) blank; prints each PNG.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: The pages shot: (name, path in the site, a text the page's HTML must hold). The notebook page is
#: the published standard run's executed notebook 02 (docs/site.md).
PAGES = (("home", "index.html", "The API reference"),
         ("api", "api/generated/histostudy.pose.estimate_pose.html", "estimate_pose"),
         ("notebook", "results/standard/notebooks/02_segmentation.html", "Table I"))


def screenshot(chromium: str, page: Path, png: Path, width: int = 1280, height: int = 1000) -> None:
    """Headless Chromium's screenshot of ``page`` (a file) into ``png``."""
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                        "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                        "--hide-scrollbars", f"--window-size={width},{height}", f"--screenshot={png}",
                        page.resolve().as_uri()], capture_output=True, text=True, timeout=120, check=True)


def not_blank(png: Path) -> bool:
    """Whether a screenshot shows something: some dark pixels (text) and some spread."""
    import cv2

    image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    return image is not None and (image < 128).mean() > 0.005 and image.std() > 10


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--site", default=str(REPO / "docs" / "_build" / "html"), help="the built site")
    parser.add_argument("--out", default=str(REPO / "docs" / "img" / "site"), help="where the PNGs go")
    args = parser.parse_args(argv)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        print("docs_screenshots: no chromium on PATH (Debian: apt-get install chromium)", file=sys.stderr)
        return 1
    site, out = Path(args.site), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failed = False
    for name, path, expected in PAGES:
        page = site / path
        if not page.is_file() or expected not in page.read_text(encoding="utf-8"):
            print(f"{page}: missing, or without {expected!r}", file=sys.stderr)
            failed = True
            continue
        png = out / f"{name}.png"
        screenshot(chromium, page, png)
        ok = not_blank(png)
        failed |= not ok
        print(f"{png} ({png.stat().st_size // 1024} KiB){'' if ok else ': (nearly) blank'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
