"""Study profiles: the parameter sets that papermill injects into the notebooks.

A profile is a TOML file (``histostudy/profiles/<name>.toml`` for the built-in ``smoke``,
``standard`` and ``paper``; any path for a user's own). Its layout::

    name = "smoke"
    description = "..."
    seed = 20230119

    [common]                 # parameters every notebook receives
    ...

    [notebooks.01_transducer_and_projections]
    render_spacing_mm = 0.125
    ...

    [training.segmentation]  # `histostudy train segmentation` (see histostudy.learning.training)
    network = { arch = "unet", base_width = 12, depth = 4 }
    ...

A notebook receives ``profile``, ``seed``, the ``[common]`` table and its own table, in that
order of precedence (its own wins). A notebook opened by hand in JupyterLab uses the defaults of
its ``parameters`` cell, which are the smoke profile's.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["PROFILE_NAMES", "Profile", "load_profile"]

PROFILE_DIR = Path(__file__).with_name("profiles")
PROFILE_NAMES = ("smoke", "standard", "paper")


@dataclass(frozen=True)
class Profile:
    """A named parameter set; see the module docstring for the file layout."""

    name: str
    seed: int
    description: str = ""
    common: dict = field(default_factory=dict)
    notebooks: dict = field(default_factory=dict)
    source: str = ""
    training: dict = field(default_factory=dict)

    def parameters_for(self, notebook: str) -> dict:
        """The papermill parameters for the notebook with stem ``notebook``."""
        params = {"profile": self.name, "seed": self.seed}
        params.update(self.common)
        params.update(self.notebooks.get(notebook, {}))
        return params


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """A built-in profile by name (``smoke``, ``standard``, ``paper``) or a TOML file by path."""
    text = os.fspath(name_or_path)
    if text in PROFILE_NAMES:
        path = PROFILE_DIR / f"{text}.toml"
    elif text.endswith(".toml") and Path(text).is_file():
        path = Path(text)
    else:
        raise ValueError(
            f"profile {text!r} is unknown: expected one of {', '.join(PROFILE_NAMES)} or the path of a .toml file"
        )
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    try:
        seed = int(data["seed"])
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"profile file {path} must set an integer 'seed', got {data.get('seed')!r}") from None
    notebooks = data.get("notebooks", {})
    if not isinstance(notebooks, dict) or not all(isinstance(v, dict) for v in notebooks.values()):
        raise ValueError(f"profile file {path}: [notebooks.<name>] entries must be tables")
    training = data.get("training", {})
    if not isinstance(training, dict) or not all(isinstance(v, dict) for v in training.values()):
        raise ValueError(f"profile file {path}: [training.<task>] entries must be tables")
    return Profile(
        name=str(data.get("name", path.stem)),
        seed=seed,
        description=str(data.get("description", "")),
        common=dict(data.get("common", {})),
        notebooks={k: dict(v) for k, v in notebooks.items()},
        source=str(path),
        training={k: dict(v) for k, v in training.items()},
    )
