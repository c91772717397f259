"""Sphinx configuration of the documentation site (``make docs``; docs/site.md says how it is built).

The site is the Markdown pages of docs/ (MyST), the API reference generated from the curated API's
docstrings (one page per public name, listed from each package's ``__all__``), the notebooks with the
outputs of the published standard run (docs/results/standard/notebooks; not executed here; the page
listing them is generated too) and the published report (report.html, linked from the home page).
"""

from __future__ import annotations

import importlib
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
sys.path.insert(0, str(REPO))

import histostudy  # noqa: E402  (the checkout's, whatever is installed)

project = "histostudy"
author = "The histostudy developers"
copyright = "2026, The histostudy developers"  # noqa: A001
release = version = histostudy.__version__

extensions = ["myst_nb", "sphinx.ext.autodoc", "sphinx.ext.autosummary", "sphinx.ext.napoleon"]
# .rst first: autosummary writes its per-name pages with the first suffix, and they are reStructuredText
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "results/*/[0-9]*/**", "results/*/REPORT.md", "results/*/*/README.md",
                    "**/.ipynb_checkpoints"]

html_theme = "pydata_sphinx_theme"
html_title = f"histostudy {release}"
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}

# MyST: headings get ids (docs link sections by them), GitHub's alerts and $ math are read
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath", "colon_fence"]
# the notebooks are shown as the published standard run left them, never executed by the build
nb_execution_mode = "off"

autosummary_generate = True
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_typehints = "description"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# a class's "Attributes:" as fields of its description, not as attributes autodoc documents again
napoleon_use_ivar = True

#: The subpackages of the curated API, in the reference's order.
API_PACKAGES = ("core", "geometry", "transducer", "imaging", "learning", "pose", "calibration", "robot", "treatment",
                "lab", "study", "reporting")


def _defining_module(package: str, name: str) -> str:
    """The module of ``histostudy.<package>`` that assigns the constant ``name`` (its ``#:`` comment
    is its documentation there)."""
    root = importlib.import_module(f"histostudy.{package}")
    # the modules the package imported (importing every module would run a script module's main)
    candidates = sorted(m for m in sys.modules if m == root.__name__ or m.startswith(root.__name__ + "."))
    for module_name in candidates:
        module = sys.modules[module_name]
        if not getattr(module, "__file__", None):
            continue
        source = Path(module.__file__).read_text(encoding="utf-8")
        if name in vars(module) and (f"\n{name} =" in source or f"\n{name}: " in source):
            return module_name
    raise LookupError(f"histostudy.{package}.{name}: no module of the package assigns it")


def _write_api_pages() -> None:
    """docs/api/<package>.rst: an autosummary of each package's ``__all__`` (each function and class
    its own page), and its constants with their ``#:`` documentation."""
    import inspect

    folder = DOCS / "api"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    for name in API_PACKAGES:
        module = importlib.import_module(f"histostudy.{name}")
        names = sorted(getattr(module, "__all__", ()))
        constants = [n for n in names if not (inspect.isclass(getattr(module, n)) or callable(getattr(module, n))
                                              or inspect.ismodule(getattr(module, n)))]
        summary = (module.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        title = f"histostudy.{name}"
        lines = [title, "=" * len(title), "", summary, "", f".. currentmodule:: histostudy.{name}", "",
                 ".. autosummary::", "   :toctree: generated", ""]
        lines += [f"   {n}" for n in names if n not in constants]
        if constants:
            lines += ["", "Constants", "---------", ""]
            for n in constants:
                lines += [f".. autodata:: {_defining_module(name, n)}.{n}", "   :no-value:", ""]
        (folder / f"{name}.rst").write_text("\n".join(lines) + "\n", encoding="utf-8")
    index = ["API reference", "=============", "",
             "Every name a subpackage's ``__init__`` lists in ``__all__``, with its docstring.", "",
             ".. toctree::", "   :maxdepth: 1", ""] + [f"   {n}" for n in API_PACKAGES]
    (folder / "index.rst").write_text("\n".join(index) + "\n", encoding="utf-8")


_write_api_pages()

#: Where ``histostudy publish`` puts the published standard run's executed notebooks.
PUBLISHED_NOTEBOOKS = DOCS / "results" / "standard" / "notebooks"


def _write_notebooks_page() -> None:
    """docs/notebooks.md: the published standard run's executed notebooks, as that run left them; a
    run published before ``histostudy publish`` kept them has none, and the page says so."""
    executed = sorted(PUBLISHED_NOTEBOOKS.glob("[0-9][0-9]_*.ipynb"))
    lines = ["# The study", "",
             "The study's notebooks as the published standard run (profile `standard`: the paper's study sizes; "
             "`docs/results/standard`) executed them. Each sets its numbers beside the paper's, and the "
             "[report](results/standard/report.html) gathers them. Re-run them with "
             "`histostudy reproduce --profile standard`, or open them in JupyterLab (`make lab`).", ""]
    if executed:
        lines += ["```{toctree}", ":maxdepth: 1", ""]
        lines += [p.relative_to(DOCS).with_suffix("").as_posix() for p in executed] + ["```"]
    else:
        lines += ["The published run was published before `histostudy publish` kept the executed notebooks, so "
                  "they are not shown here yet: the next published run brings them. Until then the "
                  "[report](results/standard/report.html) holds every number, table and figure of the run."]
    (DOCS / "notebooks.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


_write_notebooks_page()


def _check_reference(app, exception) -> None:
    """Every public name of the curated API has its reference: a page of its own, or (a constant)
    its entry on its package's page."""
    import inspect

    if exception is not None or app.builder.format != "html":
        return
    out, missing = Path(app.outdir) / "api", []
    for name in API_PACKAGES:
        module = importlib.import_module(f"histostudy.{name}")
        page = (out / f"{name}.html").read_text(encoding="utf-8")
        for public in module.__all__:
            obj = getattr(module, public)
            if inspect.isclass(obj) or callable(obj) or inspect.ismodule(obj):
                if not (out / "generated" / f"histostudy.{name}.{public}.html").is_file():
                    missing.append(f"histostudy.{name}.{public}")
            elif f'id="histostudy.{name}.' not in page or f".{public}\"" not in page:
                missing.append(f"histostudy.{name}.{public} (constant)")
    if missing:
        raise RuntimeError(f"the API reference lacks {len(missing)} public names: {', '.join(missing)}")


def setup(app):
    app.connect("build-finished", _check_reference)
