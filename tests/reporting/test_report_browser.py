"""report.html in a real headless browser (Debian's Chromium) at a phone's width: the page loads,
its images are embedded and decode, its tables sit in scrolling divs, the page itself does not
scroll sideways at 390 px, and the screenshot is not blank. Skipped where no ``chromium`` is
installed.

Headless Chromium lays a page out at 500 px or more while it loads and at the requested 390 px
only for the screenshot, so the sideways-scroll probe runs on ``resize`` too and paints its verdict
into the screenshot: a bar at the top, green when the content fits the window, red when it does not.
"""

import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pytest
from PIL import Image

from histostudy.reporting import build_report

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium)")

# Added only to copies of the report inside these tests (the report itself has no script).
IMAGES_PROBE = ("<script>addEventListener('load',()=>{document.body.dataset.imagesLoaded="
                "[...document.images].every(i=>i.complete&&i.naturalWidth>0);});</script>")
WIDTH_PROBE = ("<script>function probe(){const d=document.documentElement;let bar=document.getElementById('probe');"
               "if(!bar){bar=document.createElement('div');bar.id='probe';bar.style.cssText='position:fixed;top:0;"
               "left:0;width:100%;height:8px;z-index:99';document.body.appendChild(bar);}"
               "bar.style.background=d.scrollWidth<=innerWidth?'rgb(0,255,0)':'rgb(255,0,0)';}"
               "addEventListener('load',probe);addEventListener('resize',probe);</script>")
GREEN, RED = (0, 255, 0), (255, 0, 0)


def _chromium(tmp_path, *args, timeout=60):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
           "--window-size=390,844", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=True)


class _Dom(HTMLParser):
    def __init__(self):
        super().__init__()
        self.stack, self.images, self.tables, self.body = [], [], [], {}

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs.get("src", ""))
            return
        if tag == "table":
            parent = self.stack[-1] if self.stack else ("", {})
            self.tables.append(parent[0] == "div" and parent[1].get("class") == "table-scroll")
        if tag == "body":
            self.body = attrs
        if tag not in ("meta", "br", "hr", "input", "link"):
            self.stack.append((tag, attrs))

    def handle_endtag(self, tag):
        while self.stack and self.stack.pop()[0] != tag:  # Chromium's serialisation is well formed
            pass


@pytest.fixture
def report(folder):
    folder.section("01_demo", compare=[dict(key="angles.azimuth.mae", label="azimuth MAE", ours=(24.6, 31.3),
                                            unit="deg")],
                   tables=[("variants", folder.wide_table(), "Centre error per mode | map kind (mm)")], image=True,
                   stand_ins=[("VGG19 on GPU", "a CPU VGG19")])
    return build_report(folder.root, folder.run(parameters={"01_demo": {"n_eval_images": 4}}))[1]


def _probed(report, tmp_path, probe):
    copy = tmp_path / f"probed-{len(list(tmp_path.glob('probed-*')))}.html"
    copy.write_text(report.read_text(encoding="utf-8").replace("</body>", probe + "</body>"), encoding="utf-8")
    return copy.as_uri()


def test_dom_in_chromium_has_embedded_images_and_wrapped_tables(report, tmp_path):
    dom = _Dom()
    dom.feed(_chromium(tmp_path, "--dump-dom", _probed(report, tmp_path, IMAGES_PROBE)).stdout)
    assert dom.images and all(src.startswith("data:image/png;base64,") for src in dom.images)
    assert dom.tables and all(dom.tables), "every table inside its scrolling div"
    assert dom.body.get("data-images-loaded") == "true", "every embedded image decoded"


def test_screenshot_at_phone_width_fits_and_is_not_blank(report, tmp_path):
    shot = tmp_path / "phone.png"
    _chromium(tmp_path, f"--screenshot={shot}", _probed(report, tmp_path, WIDTH_PROBE))
    rgb = np.asarray(Image.open(shot).convert("RGB"))
    assert rgb.shape == (844, 390, 3)
    assert tuple(rgb[3, 195]) != RED, "the page scrolls sideways at 390 px"
    assert tuple(rgb[3, 195]) == GREEN, "the width probe did not run"
    page = rgb[20:].mean(axis=2)
    assert (page < 200).mean() > 0.01 and page.std() > 10, "the screenshot is (nearly) blank"
