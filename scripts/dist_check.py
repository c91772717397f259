"""The package as a user installs it, away from the checkout (``make dist-check``): the sdist and the
wheel built by ``python -m build``, the wheel installed (not editable) into a fresh virtual
environment in a temporary folder, and there, with the checkout out of reach:

1. ``histostudy --version`` names this version;
2. the shipped networks load from the installed package (``default_segmenter``, ``default_vgg19``);
3. the README's lab block ("Your own lab") runs as written, and its commands' summaries are all there;
4. ``histostudy reproduce --profile smoke --only 01`` runs notebook 01 from the packaged notebooks.

Prints the wheel's and the sdist's sizes and each step's time; exits 1 at the first failure, with
its output. ``TORCH_SPEC`` and ``TORCH_PIP_ARGS`` (as the Makefile's) choose the torch wheel
installed first.

Usage::

    python scripts/dist_check.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readme_lab_block() -> str:
    """The bash block of the README's "Your own lab" section (the one tests/test_readme.py runs)."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    start = text.index("\n## Your own lab\n")
    end = text.find("\n## ", start + 1)
    (block,) = [b for lang, b in re.findall(r"```(\w*)\n(.*?)```", text[start:end], flags=re.S) if lang == "bash"]
    return block


class Check:
    """Runs the steps, each timed, stopping at the first failure with its output."""

    def __init__(self, env: dict, cwd: Path):
        self.env, self.cwd = env, cwd

    def run(self, title: str, args: list[str], timeout: int = 1800) -> str:
        t0 = time.monotonic()
        done = subprocess.run(args, cwd=self.cwd, env=self.env, capture_output=True, text=True, timeout=timeout)
        print(f"[{time.monotonic() - t0:6.1f} s] {title}: exit {done.returncode}", flush=True)
        if done.returncode != 0:
            print(f"--- stdout\n{done.stdout[-6000:]}\n--- stderr\n{done.stderr[-6000:]}", flush=True)
            raise SystemExit(1)
        return done.stdout


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", default=None, help="work in this folder and keep it (default: a temporary one)")
    args = parser.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="histostudy-dist-check-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        return _check(work)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


def _check(work: Path) -> int:
    sys.path.insert(0, str(REPO))
    from histostudy import __version__

    dist, venv, home = work / "dist", work / "venv", work / "user"
    home.mkdir(exist_ok=True)
    # no path back to the checkout: not on PYTHONPATH, not the working folder
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    build = Check(env, REPO)
    build.run("python -m build (sdist, then the wheel from it)", [sys.executable, "-m", "build", "--outdir",
                                                                   str(dist), str(REPO)])
    wheel, = dist.glob("histostudy-*.whl")
    sdist, = dist.glob("histostudy-*.tar.gz")
    print(f"wheel {wheel.name}: {wheel.stat().st_size / 2**20:.1f} MiB; sdist {sdist.name}: "
          f"{sdist.stat().st_size / 2**20:.1f} MiB")

    build.run("python -m venv", [sys.executable, "-m", "venv", str(venv)])
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet"]
    build.run("pip install torch", pip + os.environ.get("TORCH_PIP_ARGS", "").split()
              + [os.environ.get("TORCH_SPEC", "torch==2.13.0")])
    build.run("pip install the wheel", pip + [str(wheel)])

    user = Check({**env, "PATH": f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"}, home)
    version = user.run("histostudy --version", ["histostudy", "--version"]).strip()
    if version != f"histostudy {__version__}":
        print(f"histostudy --version printed {version!r}, expected 'histostudy {__version__}'")
        return 1
    found = user.run("the shipped networks load from the installed package", ["python", "-c", (
        "import json, histostudy\n"
        "from histostudy.learning import MODELS_DIR, default_segmenter, default_vgg19\n"
        "print(json.dumps({'package': histostudy.__file__, 'models': str(MODELS_DIR),\n"
        "                  'unet': default_segmenter() is not None, 'vgg19': default_vgg19() is not None}))")])
    where = json.loads(found)
    print(f"    {where}")
    if not (where["unet"] and where["vgg19"] and str(venv) in where["package"] and str(venv) in where["models"]):
        print("the installed package did not load its own shipped networks")
        return 1

    script = "set -euo pipefail\ntrap 'kill ${controller:-} $(jobs -p) 2>/dev/null || true' EXIT\n" + readme_lab_block()
    out = user.run("the README's lab block", ["bash", "-c", script])
    commands = sorted(json.loads(line).get("event") or json.loads(line)["command"] for line in out.splitlines())
    expected = sorted(["lab-dataset", "pose", "calibrate", "target", "target", "target", "listening", "send",
                       "summary"])
    if commands != expected:
        print(f"the lab block's summaries were {commands}, expected {expected}")
        return 1

    reports = home / "reports"
    user.run("histostudy reproduce --profile smoke --only 01",
             ["histostudy", "reproduce", "--profile", "smoke", "--only", "01", "--output", str(reports),
              "--no-progress"])
    record = json.loads((reports / "run.json").read_text())
    statuses = [(n["name"], n["status"]) for n in record["notebooks"]]
    if statuses != [("01_transducer_and_projections", "ok")] or str(venv) not in record["notebooks_dir"]:
        print(f"reproduce ran {statuses} from {record['notebooks_dir']}, expected notebook 01 only, ok, "
              f"from the packaged notebooks")
        return 1
    print(f"    notebooks: {record['notebooks_dir']}")
    print("dist-check: the wheel works outside the checkout")
    return 0


if __name__ == "__main__":
    sys.exit(main())
