"""Study profiles: the parameter sets that papermill injects into the notebooks, read from TOML
(``histostudy/reporting/profiles/<name>.toml`` for the built-in ones, any path for a user's own) and
checked against the notebooks' ``parameters`` cells (docs/report.md, "Profiles")."""

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
#: The built-in profiles (``profiles/<name>.toml``), from a first look to the paper's study sizes.
PROFILE_NAMES = ("smoke", "standard", "paper")

#: The top-level keys and tables of a profile file.
TOP_LEVEL_KEYS = ("name", "description", "seed", "common", "notebooks", "training")
#: Notebook parameters the run sets itself (the profile's name and seed, ``--output``); a table that
#: set them would either be overwritten unseen or disagree with the seed recorded in run.json.
RUN_PARAMETERS = ("profile", "seed", "output_dir")


@dataclass(frozen=True)
class Profile:
    """A named parameter set, as :func:`load_profile` reads it (docs/report.md, "Profiles").

    Args:
        name: the profile's name (the file's ``name``, else its stem).
        seed: the run's seed, a non-negative integer, given to every notebook.
        description: one line on what the profile is for (the report's banner quotes it).
        common: the ``[common]`` table: parameters every notebook receives.
        notebooks: ``{notebook stem: table}``, each notebook's own parameters (they win over
            ``common``).
        source: the TOML file it was read from ("" for one built in code).
        training: ``{task: table}``, the ``[training.<task>]`` tables of ``histostudy train``.
    """

    name: str
    seed: int
    description: str = ""
    common: dict = field(default_factory=dict)
    notebooks: dict = field(default_factory=dict)
    source: str = ""
    training: dict = field(default_factory=dict)

    def parameters_for(self, notebook: str) -> dict:
        """The papermill parameters for one notebook: ``profile``, ``seed``, ``common``, then its
        own table (later wins).

        Args:
            notebook: the notebook's stem (``"04_pose_estimation"``).

        Returns:
            A new dict of parameter name -> value.
        """
        params = {"profile": self.name, "seed": self.seed}
        params.update(self.common)
        params.update(self.notebooks.get(notebook, {}))
        return params


def load_profile(name_or_path: str | os.PathLike) -> Profile:
    """Read a built-in profile by name or a profile's TOML file by path, checking its layout.

    Args:
        name_or_path: ``"smoke"``, ``"standard"``, ``"paper"``, or the path of an existing ``.toml``
            file.

    Returns:
        The :class:`Profile`, with ``source`` the file read.

    Raises:
        ValueError: ``name_or_path`` is neither a built-in name nor an existing ``.toml`` file; the
            file is not valid TOML; or its layout is wrong (a top-level key other than ``name``,
            ``description``, ``seed``, ``common``, ``notebooks``, ``training``; ``seed`` missing or not
            a non-negative integer; ``name`` or ``description`` not a string; a table that is not
            one). All problems are named at once.
    """
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
    """The names assigned in the cell tagged ``parameters`` of a notebook, in order.

    The cell is parsed with :mod:`ast` (tuple targets, annotations, values over several lines); a
    cell that is not plain Python (an IPython magic) falls back to papermill's line-based reader.

    Args:
        notebook: the ``.ipynb`` path.

    Returns:
        The names; empty when the notebook has no such cell.

    Raises:
        ValueError: the file cannot be read as a ``.ipynb`` (JSON) file.
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
    """Check that ``profile`` fits the notebooks a run would find.

    Every ``[notebooks.<stem>]`` names one of the notebooks, its keys are that notebook's parameters
    (:func:`notebook_parameters`), each ``[common]`` key is a parameter of at least one notebook, no
    table sets ``profile``, ``seed`` or ``output_dir``, and ``seed`` is a non-negative integer.

    Args:
        profile: the profile to check.
        notebooks: the ``.ipynb`` paths of the run's folder.

    Raises:
        ValueError: ``notebooks`` is empty, or any rule above is broken (all problems at once, each
            with the nearest valid name); or a notebook cannot be read.
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
