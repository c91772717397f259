"""Study profiles: the parameter sets that papermill injects into the notebooks.

A profile is a TOML file (``histostudy/reporting/profiles/<name>.toml`` for the built-in ``smoke``,
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

Validation. :func:`load_profile` refuses a file whose layout is wrong: a top-level key or table
other than the six above, a ``seed`` that is not a non-negative integer (``1.7`` and ``true``
included), a ``name`` or ``description`` that is not a string, a ``[common]``, ``[notebooks.*]``
or ``[training.*]`` that is not a table. :func:`validate_profile` checks the profile against the
notebooks of the run's folder, whose parameters are the names assigned in their cell tagged
``parameters`` (:func:`notebook_parameters`): every ``[notebooks.<stem>]`` must name one of them;
each of its keys must be a parameter of that notebook; each ``[common]`` key must be a parameter
of at least one of them (it still goes to every notebook; papermill injects it, with a warning,
where the cell lacks it, as it always has). ``profile``, ``seed`` and ``output_dir`` are set by
the run itself, so no table may set them. Each error names the file, the table, the key and the
nearest valid name. The ``[training.<task>]`` tables are checked by ``histostudy train``
(:meth:`histostudy.learning.TrainingConfig.from_table`).
"""

from __future__ import annotations

import ast
import difflib
import json
import os
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["PROFILE_NAMES", "Profile", "load_profile", "notebook_parameters", "validate_profile"]

PROFILE_DIR = Path(__file__).with_name("profiles")
PROFILE_NAMES = ("smoke", "standard", "paper")

#: The top-level keys and tables of a profile file.
TOP_LEVEL_KEYS = ("name", "description", "seed", "common", "notebooks", "training")
#: Notebook parameters the run sets itself (the profile's name and seed, ``--output``); a table that
#: set them would either be overwritten unseen or disagree with the seed recorded in run.json.
RUN_PARAMETERS = ("profile", "seed", "output_dir")


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
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"profile file {path} is not valid TOML: {exc}") from None
    problems = [f"unknown top-level key {key!r}{_did_you_mean(key, TOP_LEVEL_KEYS)} "
                f"(expected only {', '.join(TOP_LEVEL_KEYS)})" for key in data if key not in TOP_LEVEL_KEYS]
    if "seed" not in data:
        problems.append("'seed' is missing: expected a non-negative integer such as seed = 20230119")
    else:
        problems += _seed_problems(data["seed"])
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            problems.append(f"{key!r} must be a string, got {data[key]!r} ({type(data[key]).__name__})")
    common = data.get("common", {})
    if not isinstance(common, dict):
        problems.append(f"'common' must be a table [common], got {common!r}")
    for key in ("notebooks", "training"):
        tables = data.get(key, {})
        if not isinstance(tables, dict) or not all(isinstance(v, dict) for v in tables.values()):
            placeholder = "<stem>" if key == "notebooks" else "<task>"
            problems.append(f"[{key}.{placeholder}] entries must be tables, got {key} = {tables!r}")
    _raise_problems(f"profile file {path}", problems)
    return Profile(
        name=data.get("name", path.stem),
        seed=data["seed"],
        description=data.get("description", ""),
        common=dict(common),
        notebooks={k: dict(v) for k, v in data.get("notebooks", {}).items()},
        source=str(path),
        training={k: dict(v) for k, v in data.get("training", {}).items()},
    )


def notebook_parameters(notebook: str | os.PathLike) -> tuple[str, ...]:
    """The names assigned in the cell tagged ``parameters`` of ``notebook`` (an .ipynb path), in order.

    Empty when the notebook has no such cell (papermill then injects its parameters at the top).
    The cell is parsed with :mod:`ast`, which reads any Python assignment exactly (tuple targets,
    annotations, values over several lines) without asking for a kernel; a cell that is not plain
    Python (an IPython magic) falls back to papermill's own line-based reader.
    """
    path = Path(notebook)
    try:
        nb = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"notebook {str(path)!r} could not be read as a .ipynb file: {exc}") from None
    cells = [c for c in nb.get("cells", []) if "parameters" in c.get("metadata", {}).get("tags", [])]
    if not cells:
        return ()
    source = cells[0].get("source", "")
    source = "".join(source) if isinstance(source, list) else source
    try:
        tree = ast.parse(source)
    except SyntaxError:
        import papermill

        return tuple(papermill.inspect_notebook(str(path)))
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign):
            targets = [node.target]
        else:
            continue
        for target in targets:
            names += [n.id for n in ast.walk(target) if isinstance(n, ast.Name) and n.id not in names]
    return tuple(names)


def validate_profile(profile: Profile, notebooks: Iterable[str | os.PathLike]) -> None:
    """Raise ValueError unless ``profile`` fits ``notebooks`` (the .ipynb paths a run would find).

    The rules are the module docstring's: every ``[notebooks.<stem>]`` names one of the notebooks,
    its keys are that notebook's parameters, each ``[common]`` key is a parameter of at least one
    notebook, no table sets ``profile``, ``seed`` or ``output_dir``, and ``seed`` is a non-negative
    integer. All problems are reported at once, each with the nearest valid name.
    """
    paths = [Path(p) for p in notebooks]
    if not paths:
        raise ValueError("notebooks is empty: expected the .ipynb paths the profile's tables refer to")
    params = {p.stem: notebook_parameters(p) for p in paths}
    folders = sorted({str(p.parent) for p in paths})
    # A profile run against another --notebooks folder fails on every table: say which folder.
    found = f"(notebooks in {', '.join(folders)}: {', '.join(params)})"
    problems = _seed_problems(profile.seed)
    every = sorted({name for names in params.values() for name in names} - set(RUN_PARAMETERS))
    for key in profile.common:
        if key in RUN_PARAMETERS:
            problems.append(_run_parameter_problem(key, "[common]"))
        elif key not in every:
            problems.append(f"key {key!r} in [common] is a parameter of no notebook{_did_you_mean(key, every)} "
                            + found)
    stems = list(params)
    for stem, table in profile.notebooks.items():
        if stem not in params:
            problems.append(f"table [notebooks.{stem}] names no notebook{_did_you_mean(stem, stems, '[notebooks.{}]')} "
                            + found)
            continue
        valid = [name for name in params[stem] if name not in RUN_PARAMETERS]
        for key in table:
            if key in RUN_PARAMETERS:
                problems.append(_run_parameter_problem(key, f"[notebooks.{stem}]"))
            elif key not in valid:
                problems.append(f"key {key!r} in [notebooks.{stem}] is not a parameter of notebook {stem}"
                                f"{_did_you_mean(key, valid)} (its parameters: {', '.join(valid) or 'none'})")
    _raise_problems(f"profile file {profile.source}" if profile.source else f"profile {profile.name!r}", problems)


def _seed_problems(seed) -> list[str]:
    # bool is an int subclass and a float would be truncated: both are typos of an integer seed.
    if isinstance(seed, bool) or not isinstance(seed, int):
        return [f"'seed' must be a non-negative integer, got {seed!r} ({type(seed).__name__})"]
    if seed < 0:
        return [f"'seed' must be a non-negative integer (numpy refuses negative seeds), got {seed!r}"]
    return []


def _run_parameter_problem(key: str, table: str) -> str:
    where = {"profile": "the profile's top-level 'name'", "seed": "the profile's top-level 'seed'",
             "output_dir": "histostudy reproduce --output"}[key]
    return f"key {key!r} in {table} is set by the run itself (from {where}): remove it"


def _did_you_mean(word: str, choices: Sequence[str], template: str = "{!r}") -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f"; did you mean {template.format(close[0])}?" if close else ""


def _raise_problems(where: str, problems: list[str]) -> None:
    if len(problems) == 1:
        raise ValueError(f"{where}: {problems[0]}")
    if problems:
        raise ValueError(f"{where} has {len(problems)} problems:\n" + "\n".join(f"  - {p}" for p in problems))
