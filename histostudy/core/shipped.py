"""Where the files shipped with the package are: the trained networks and the study's notebooks, in a
checkout (``data/models``, ``notebooks/``) or inside an installed wheel (``histostudy/_data/``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["SHIPPED_KINDS", "shipped_dir"]

#: The kinds of shipped files: where a checkout keeps each, relative to the repository's root.
SHIPPED_KINDS = {"models": Path("data") / "models", "notebooks": Path("notebooks")}

_CHECKOUT_ROOT = Path(__file__).resolve().parents[2]


def shipped_dir(kind: str) -> Path:
    """The folder of one kind of shipped files.

    A wheel carries them inside the package (``histostudy/_data/<kind>``, found through
    ``importlib.resources``); a checkout, editable install included, keeps them where its developers
    edit them (:data:`SHIPPED_KINDS`). The package's copy is preferred where both exist.

    Args:
        kind: ``"models"`` (the trained networks' weights and manifests) or ``"notebooks"``.

    Returns:
        The folder (it may not exist: a checkout without the files, a wheel built without them).

    Raises:
        ValueError: an unknown ``kind``.
    """
    if kind not in SHIPPED_KINDS:
        raise ValueError(f"kind must be one of {sorted(SHIPPED_KINDS)}, got {kind!r}")
    packaged = Path(str(resources.files("histostudy").joinpath("_data", kind)))
    return packaged if packaged.is_dir() else _CHECKOUT_ROOT / SHIPPED_KINDS[kind]
