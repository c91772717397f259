"""Where the shipped networks and notebooks are: a checkout's folders, or the copies a wheel carries
inside the package (which win where both exist)."""

from pathlib import Path

import pytest

import histostudy
from histostudy.core import shipped as shipped_module
from histostudy.core import shipped_dir

CHECKOUT = Path(histostudy.__file__).resolve().parents[1]


def test_a_checkout_finds_its_own_folders():
    assert shipped_dir("models") == CHECKOUT / "data" / "models"
    assert shipped_dir("notebooks") == CHECKOUT / "notebooks"
    assert (shipped_dir("models") / "unet_standard.safetensors").is_file()
    assert len(list(shipped_dir("notebooks").glob("0*_*.ipynb"))) == 7


def test_an_installed_wheel_finds_the_copies_inside_the_package(tmp_path, monkeypatch):
    package = tmp_path / "site-packages" / "histostudy"
    (package / "_data" / "models").mkdir(parents=True)
    monkeypatch.setattr(shipped_module.resources, "files", lambda name: package)
    assert shipped_dir("models") == package / "_data" / "models"
    assert shipped_dir("notebooks") == CHECKOUT / "notebooks"  # not packaged here: the checkout's


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="kind must be one of \\['models', 'notebooks'\\], got 'weights'"):
        shipped_dir("weights")
