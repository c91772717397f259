"""A finished run published in the repository (``docs/results/<profile>``), its headline in the
README, and the check that its parameters are still the profile's (docs/report.md, "Published
runs")."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

from histostudy.core import atomic_write_json, atomic_write_text
from histostudy.core.provenance import REPO_ROOT

from .headline import headline_markdown
from .pages import MAX_TABLE_ROWS, SECTION_PAGE, anchors_of, relink
from .pipeline import discover_notebooks
from .profiles import Profile, load_profile
from .report import RESULTS_FILE, RUN_FILE, build_report, load_section
from .section_keys import KEY_FILE
from .twins import results_coverage

__all__ = ["PUBLISHED_SUFFIXES", "README_HEADLINE_BEGIN", "README_HEADLINE_END", "publish_run", "readme_headline",
           "replace_readme_headline", "stale_parameters"]

#: The files of a section folder that are published (results, tables, figures).
PUBLISHED_SUFFIXES = (".json", ".md", ".csv", ".png", ".svg")
#: The published files that are text, which may name the machine's paths.
PUBLISHED_TEXT_SUFFIXES = (".json", ".md", ".csv", ".svg")
#: The markers of the README's block that holds the published headline.
README_HEADLINE_BEGIN, README_HEADLINE_END = "<!-- published-headline:begin -->", "<!-- published-headline:end -->"
_MAX_FILE_BYTES = 4 * 1024 * 1024


def _load_run(folder: Path) -> dict:
    try:
        with open(folder / RUN_FILE, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError) as exc:
        raise ValueError(f"run_dir {str(folder)!r} holds no readable {RUN_FILE} (a histostudy reproduce "
                         f"output folder was expected): {exc}") from None


def _check_complete(run: dict, folder: Path, notebooks_dir, allow_partial: bool) -> list[str]:
    """The notebooks of ``notebooks_dir`` the run did not run (allowed only with ``allow_partial``)."""
    not_ok = [n["name"] for n in run.get("notebooks", []) if n.get("status") != "ok"]
    if not_ok:
        raise ValueError(f"run_dir {str(folder)!r}: notebooks {', '.join(not_ok)} did not finish (status in "
                         f"{RUN_FILE}); a run is published only when every section it lists finished")
    ran = {n["name"] for n in run.get("notebooks", [])}
    missing = [p.stem for p in discover_notebooks(notebooks_dir) if p.stem not in ran] if notebooks_dir else []
    if missing and not allow_partial:
        raise ValueError(f"run_dir {str(folder)!r} did not run notebooks {', '.join(missing)}; run them "
                         "(histostudy reproduce resumes, keeping the finished sections) or publish with "
                         "allow_partial=True, which names them in the report")
    return missing


def _relative_run(run: dict) -> dict:
    out = json.loads(json.dumps(run))
    for entry in out.get("notebooks", []):
        if "output_dir" in entry:
            entry["output_dir"] = entry["name"]
        if isinstance(entry.get("parameters"), dict) and "output_dir" in entry["parameters"]:
            entry["parameters"]["output_dir"] = entry["name"]
    out.get("provenance", {}).get("machine", {}).pop("executable", None)
    out.pop("notebooks_dir", None)  # a path of the machine that ran it
    if isinstance(out.get("profile_source"), str) and os.path.isabs(out["profile_source"]):
        out["profile_source"] = _package_relative(out["profile_source"])
    if out.get("failure"):
        out["failure"]["executed_notebook"] = None
    return out


def _package_relative(path: str) -> str:
    """A shipped file's path from the package's folder on (``histostudy/reporting/profiles/x.toml``),
    else its name: the machine's checkout left out."""
    parts = Path(path).parts
    if "histostudy" not in parts:
        return Path(path).name
    return "/".join(parts[len(parts) - 1 - parts[::-1].index("histostudy"):])


def _copy_section(source: Path, target: Path) -> None:
    target.mkdir(parents=True)
    for path in sorted(source.rglob("*")):
        if path.is_file() and path.suffix in PUBLISHED_SUFFIXES and path.stat().st_size <= _MAX_FILE_BYTES:
            dest = target / path.relative_to(source)
            dest.parent.mkdir(parents=True, exist_ok=True)
            if path.name == KEY_FILE and path.parent == source:
                record = json.loads(path.read_text(encoding="utf-8"))
                (record.get("machine") or {}).pop("executable", None)  # a path of the machine that ran it
                atomic_write_json(dest, record)
            else:
                shutil.copyfile(path, dest)  # a new file: mode 0o666 less the umask, as open() makes it


def _publish_notebook(source: Path, target: Path, name: str) -> None:
    """The executed notebook ``source`` written to ``target``, papermill's input and output paths
    named by the notebook alone (:func:`_strip_machine_paths` takes the other paths out)."""
    notebook = json.loads(source.read_text(encoding="utf-8"))
    papermill = notebook.get("metadata", {}).get("papermill", {})
    for key in ("input_path", "output_path"):
        if key in papermill:
            papermill[key] = f"notebooks/{name}.ipynb"
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, json.dumps(notebook, indent=1, ensure_ascii=False) + "\n")


def _machine_roots(run: dict, source: Path) -> list[str]:
    """The folders of the machine that made the run, as its files name them, longest first: the
    run's folder (the parent of each section's ``output_dir``, and of the ``output_dir`` each
    executed notebook ran with: a section kept from a run in another folder), and the checkout it
    ran from (above its shipped profile, and this package's)."""
    folders = set()
    for entry in run.get("notebooks", []):
        for output_dir in (entry.get("output_dir"), (entry.get("parameters") or {}).get("output_dir")):
            if isinstance(output_dir, str) and os.path.isabs(output_dir):
                folders.add(str(Path(output_dir).parent))
        executed = source / "notebooks" / f"{entry['name']}.ipynb"
        if executed.is_file():
            papermill = json.loads(executed.read_text(encoding="utf-8")).get("metadata", {}).get("papermill", {})
            ran_with = (papermill.get("parameters") or {}).get("output_dir")
            if isinstance(ran_with, str) and os.path.isabs(ran_with):
                folders.add(str(Path(ran_with).parent))
    profile_source = run.get("profile_source")
    if isinstance(profile_source, str) and Path(profile_source).parts[-4:-1] == ("histostudy", "reporting", "profiles"):
        folders.add(str(Path(profile_source).parents[3]))
    folders.add(str(REPO_ROOT))
    return sorted((f.rstrip(os.sep) + os.sep for f in folders if f not in ("", os.sep)), key=len, reverse=True)


def _strip_machine_paths(folder: Path, roots: list[str]) -> None:
    """Take ``roots`` out of every published text file of ``folder``: a section's paths become
    relative to the run (``02_segmentation/results.json``), a shipped file's to the checkout
    (``data/models/unet_standard.safetensors``)."""
    for path in folder.rglob("*"):
        if path.is_file() and path.suffix in (*PUBLISHED_TEXT_SUFFIXES, ".ipynb", ".html"):
            text = path.read_text(encoding="utf-8")
            cleaned = text
            for root in roots:
                cleaned = cleaned.replace(root, "")
            if cleaned != text:
                atomic_write_text(path, cleaned)


def _drop_long_table_markdown(folder: Path) -> None:
    """Remove the Markdown copy of each table longer than :data:`~.pages.MAX_TABLE_ROWS` rows: its
    page shows it cut, report.html whole, and its CSV keeps it (``histostudy report`` renders it
    from there), so that no published Markdown file is a table of hundreds of lines."""
    for table in folder.glob("*/tables/*.md"):
        if table.with_suffix(".csv").is_file() and table.read_text(encoding="utf-8").count("\n") > MAX_TABLE_ROWS + 2:
            table.unlink()


def publish_run(run_dir: str | os.PathLike, destination: str | os.PathLike, *, allow_partial: bool = False,
                notebooks_dir: str | os.PathLike | None = None, max_html_bytes: int = 10 * 1024 * 1024) -> Path:
    """Publish the finished run of ``run_dir`` into ``destination``, replaced whole, never half-written.

    Copies what a reader needs: ``run.json`` (its paths made relative), each section's
    ``results.json``, ``section_key.json``, tables and figures (up to 4 MiB a file), and rebuilds
    ``REPORT.md``, the sections' pages and ``report.html`` there; a table longer than a page shows
    keeps its CSV only. The executed notebooks go to ``notebooks/``, the machine's paths taken out
    of them (the documentation site shows them); caches stay behind.

    Args:
        run_dir: a ``histostudy reproduce`` output folder.
        destination: the published folder (``docs/results/<profile>``); not ``run_dir`` itself.
        allow_partial: publish a run that left notebooks of ``notebooks_dir`` out; the report names
            them "not run".
        notebooks_dir: the notebooks a complete run runs (default: the repository's ``notebooks/``).
        max_html_bytes: ``report.html`` is left out above this size (bytes); ``REPORT.md`` says so.

    Returns:
        The path of the published ``REPORT.md``.

    Raises:
        ValueError: before writing anything, when ``destination`` is ``run_dir``, ``run_dir`` holds no
            readable ``run.json``, a section it lists did not finish or has no ``results.json``, or
            (unless ``allow_partial``) a notebook of ``notebooks_dir`` did not run.
    """
    from .pipeline import DEFAULT_NOTEBOOK_DIR

    source, dest = Path(run_dir).resolve(), Path(destination).resolve()
    if source == dest:
        raise ValueError(f"destination {str(dest)!r} is run_dir itself: publish into another folder")
    run = _load_run(source)
    missing = _check_complete(run, source, notebooks_dir or DEFAULT_NOTEBOOK_DIR, allow_partial)
    for entry in run["notebooks"]:
        if not (source / entry["name"] / RESULTS_FILE).is_file():
            raise ValueError(f"run_dir {str(source)!r}: section {entry['name']} has no {RESULTS_FILE}")
    staging = dest.with_name(f".{dest.name}.publishing")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        for entry in run["notebooks"]:
            _copy_section(source / entry["name"], staging / entry["name"])
        for entry in run["notebooks"]:
            executed = source / "notebooks" / f"{entry['name']}.ipynb"
            if executed.is_file():  # the docs site shows it, outputs and all (docs/conf.py)
                _publish_notebook(executed, staging / "notebooks" / executed.name, entry["name"])
        record = _relative_run(run)
        record["notebooks"] = sorted(record["notebooks"] + [{"name": name, "status": "not run"} for name in missing],
                                     key=lambda entry: entry["name"])
        atomic_write_json(staging / RUN_FILE, record)
        build_report(staging, record)
        _drop_long_table_markdown(staging)
        _strip_machine_paths(staging, _machine_roots(run, source))
        html = staging / "report.html"
        html_bytes = html.stat().st_size
        if html_bytes > max_html_bytes:
            html.unlink()
            md = staging / "REPORT.md"
            atomic_write_text(md, md.read_text(encoding="utf-8") + f"\n*report.html ({html_bytes} bytes) is not "
                              f"published: over {max_html_bytes} bytes; `histostudy report` rebuilds it.*\n")
        old = dest.with_name(f".{dest.name}.replaced")
        shutil.rmtree(old, ignore_errors=True)
        if dest.exists():
            os.replace(dest, old)
        os.replace(staging, dest)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return dest / "REPORT.md"


def stale_parameters(published_dir: str | os.PathLike, profile: str | Profile | None = None) -> list[str]:
    """Where the run published in ``published_dir`` differs from a profile's parameters.

    Args:
        published_dir: a folder :func:`publish_run` wrote.
        profile: a profile's name or file, or a :class:`~.profiles.Profile`; None takes the one the
            run names.

    Returns:
        One line per difference (the seed; per notebook, each parameter added, removed or changed);
        empty when the published numbers are those the profile makes (the code may still differ:
        its commit is in the report).

    Raises:
        ValueError: ``published_dir`` holds no readable ``run.json``, or the profile is unknown or
            malformed.
    """
    folder = Path(published_dir)
    run = _load_run(folder)
    prof = profile if isinstance(profile, Profile) else load_profile(profile or run["profile"])
    found = []
    if run.get("seed") != prof.seed:
        found.append(f"seed: published {run.get('seed')!r}, profile {prof.seed!r}")
    for entry in run.get("notebooks", []):
        if entry.get("status") == "not run":
            continue  # a partial publication names it in its report
        name = entry["name"]
        published = {k: v for k, v in entry.get("parameters", {}).items() if k != "output_dir"}
        current = prof.parameters_for(name)
        for key in sorted(set(published) | set(current)):
            if key not in current:
                found.append(f"{name}.{key}: published {published[key]!r}, not in profile {prof.name}")
            elif key not in published:
                found.append(f"{name}.{key}: profile {prof.name} has {current[key]!r}, the published run had none")
            elif json.dumps(published[key], sort_keys=True) != json.dumps(current[key], sort_keys=True):
                found.append(f"{name}.{key}: published {published[key]!r}, profile {prof.name} {current[key]!r}")
    return found


def readme_headline(published_dir: str | os.PathLike, link_prefix: str) -> str:
    """The headline table of a published run, for the README.

    Args:
        published_dir: a folder :func:`publish_run` wrote.
        link_prefix: the path of the published ``REPORT.md`` as seen from the README; the table's
            links are made to point into it, or into the section pages beside it.

    Returns:
        The table's Markdown, ending with a newline.

    Raises:
        ValueError: ``published_dir`` holds no readable ``run.json``.
    """
    folder = Path(published_dir)
    run = _load_run(folder)
    sections = {n["name"]: load_section(folder / n["name"]) for n in run.get("notebooks", [])
                if (folder / n["name"] / RESULTS_FILE).is_file()}
    text = "\n".join(headline_markdown(results_coverage(sections, run))).rstrip()
    # links to a section's anchors go to its page, as in the published REPORT.md
    page_of_anchor = {anchor: f"{page.parent.name}/{SECTION_PAGE}" for page in sorted(folder.glob(f"*/{SECTION_PAGE}"))
                      for anchor in anchors_of(page.read_text(encoding="utf-8"))}
    text = relink(text, "REPORT.md", page_of_anchor)
    base = link_prefix.rsplit("/", 1)[0] + "/" if "/" in link_prefix else ""
    text = re.sub(r"\]\((?![a-z]+:|/|#)", f"]({base}", text)  # the pages, seen from the README
    return re.sub(r"\]\(#", f"]({link_prefix}#", text) + "\n"


def replace_readme_headline(readme: str | os.PathLike, published_dir: str | os.PathLike, link_prefix: str) -> Path:
    """Put the published run's headline (:func:`readme_headline`) between the README's markers
    ``<!-- published-headline:begin -->`` and ``<!-- published-headline:end -->`` (atomically).

    Args:
        readme: the README file.
        published_dir: a folder :func:`publish_run` wrote.
        link_prefix: the path of the published ``REPORT.md`` as seen from the README.

    Returns:
        The README's path.

    Raises:
        ValueError: the README does not hold each marker exactly once, or ``published_dir`` holds no
            readable ``run.json``.
        OSError: the README cannot be read.
    """
    path = Path(readme)
    text = path.read_text(encoding="utf-8")
    if text.count(README_HEADLINE_BEGIN) != 1 or text.count(README_HEADLINE_END) != 1:
        raise ValueError(f"readme {str(path)!r} must hold {README_HEADLINE_BEGIN} and {README_HEADLINE_END} once each")
    head, rest = text.split(README_HEADLINE_BEGIN)
    _, tail = rest.split(README_HEADLINE_END)
    block = f"{README_HEADLINE_BEGIN}\n{readme_headline(published_dir, link_prefix)}{README_HEADLINE_END}"
    return atomic_write_text(path, head + block + tail)

