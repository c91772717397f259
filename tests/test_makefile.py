"""The Makefile's targets as make would run them (``make -n``): ``make lab`` adds JupyterLab's
--allow-root exactly when root runs it, and says so."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_lab_allows_root_only_as_root():
    # -o: the environment's stamp counts as made, so that make -n prints the lab's own lines only
    lines = subprocess.run(["make", "-n", "-o", ".venv/.histostudy-installed", "lab"],
                           cwd=REPO, capture_output=True, text=True, check=True).stdout
    jupyter = [line for line in lines.splitlines() if "jupyter lab" in line]
    assert len(jupyter) == 1 and "--notebook-dir=notebooks" in jupyter[0]
    assert ("--allow-root" in jupyter[0]) == (os.geteuid() == 0)
    assert "adding --allow-root" in lines  # the message, printed only as root by the shell's test
