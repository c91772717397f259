"""The docstrings name only what exists: every ``histostudy.x.y`` and ``:mod:`` reference resolves,
every bare ``name`` in a package's docstring is one of its modules or names, and no docstring names
a module path that a release removed (CHANGELOG.md, "Removed")."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re
from pathlib import Path

import pytest

import histostudy

PACKAGE = Path(histostudy.__file__).parent

#: The last part of every module path removed in 0.2.0 and 0.3.0: a docstring naming one is stale.
REMOVED_MODULE_NAMES = {
    # 0.2.0: the flat top-level shims
    "volume_io", "handeye",
    # 0.3.0: the families that became sub-packages, and the hook that kept their old paths
    "moved_modules", "pose_estimation", "pose_config", "pose_experiments", "pose_geometry", "pose_metrics",
    "pose_reference", "pose_report_tables", "pose_robustness", "pose_section", "pose_sweeps",
    "projector_comparison", "targeting_calibration", "targeting_experiment", "targeting_figures",
    "targeting_notebook", "targeting_positioning", "targeting_robots", "targeting_setup", "targeting_summary",
    "targeting_treatment", "your_data_live", "error_budget_notebook", "error_budget_summary", "lab_errors",
    "anatomy_csg", "anatomy_params", "anatomy_rays", "anatomy_scene", "anatomy_shapes", "render_device",
    "render_settings", "render_torch", "splat_kernels", "dicom_geometry", "dicom_io", "dicom_xa", "nifti_io",
    "volume_io_grid", "controller_arm", "controller_program", "controller_protocol", "controller_server",
    "rtde_connection", "rtde_units", "training_config", "training_export", "training_losses",
    "training_teacher", "tracking_input", "tracking_maps", "tracking_options", "tracking_pipeline",
    "tracking_roi", "tracking_scratch", "tracking_warm", "cost_kernels", "cost_reference",
}

DOTTED = re.compile(r"\bhistostudy(?:\.[A-Za-z_]\w*)+")
MOD_ROLE = re.compile(r":mod:`~?(\.*[\w.]*)`")
BARE = re.compile(r"``([A-Za-z_]\w*)``")


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts[-1] != "__main__":
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _docstrings(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    nodes = [tree] + [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                                   ast.ClassDef))]
    return [doc for node in nodes if (doc := ast.get_docstring(node))]


def _resolves(dotted: str) -> bool:
    """Whether ``dotted`` is a module, or a module's attribute (attribute of attribute...)."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        name = ".".join(parts[:cut])
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            continue
        obj = importlib.import_module(name)
        for attribute in parts[cut:]:
            if not hasattr(obj, attribute):
                return False
            obj = getattr(obj, attribute)
        return True
    return False


def _package_of(module: str) -> str:
    return module if MODULES[module].name == "__init__.py" else module.rsplit(".", 1)[0]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_every_reference_in_a_docstring_resolves(module):
    stale = []
    for doc in _docstrings(MODULES[module]):
        for dotted in DOTTED.findall(doc):
            if not _resolves(dotted):
                stale.append(dotted)
        for target in MOD_ROLE.findall(doc):
            if target.startswith("."):
                level = len(target) - len(target.lstrip("."))
                base = _package_of(module).split(".")
                base = base[: len(base) - level + 1]
                target = ".".join(base + ([target.lstrip(".")] if target.lstrip(".") else []))
            if not _resolves(target):
                stale.append(f":mod:`{target}`")
        stale += [f"``{name}`` (a removed module)" for name in BARE.findall(doc) if name in REMOVED_MODULE_NAMES]
    assert stale == [], f"{module}'s docstrings name what does not exist: {sorted(set(stale))}"


@pytest.mark.parametrize("package", sorted(m for m, p in MODULES.items() if p.name == "__init__.py"))
def test_a_package_s_docstring_names_only_its_modules_and_names(package):
    """The ``__init__`` docstring is what a newcomer reads first: each bare ``name`` in it is a
    module of the package (at any depth) or a name the package or one of its modules has."""
    doc = ast.get_docstring(ast.parse(MODULES[package].read_text())) or ""
    inside = [m for m in MODULES if m.startswith(package + ".")]
    names = {m.rsplit(".", 1)[1] for m in inside}
    loaded = [importlib.import_module(package)] + [importlib.import_module(m) for m in inside
                                                    if m.count(".") == package.count(".") + 1]
    unknown = [name for name in BARE.findall(doc)
               if name not in names and not any(hasattr(mod, name) for mod in loaded)]
    assert unknown == [], f"{package}'s docstring names what it does not have: {sorted(set(unknown))}"


SUBPACKAGES = sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py"))
ARCHITECTURE = PACKAGE.parent / "docs" / "architecture.md"


def test_the_architecture_page_names_only_what_exists():
    """docs/architecture.md is what a newcomer reads first: each file or folder it names in
    backquotes (under histostudy/ or the repository) exists, and each ``package.name`` it names
    resolves."""
    text = ARCHITECTURE.read_text()
    # a path may be written from the package, the repository or the subpackage it is about
    bases = [PACKAGE.parent, PACKAGE, *(p for p in PACKAGE.rglob("*") if p.is_dir() and p.name != "__pycache__")]
    stale = []
    for token in re.findall(r"`([^`\s]+)`", text):
        token = token.rstrip(",.;:")
        if "/" in token and re.fullmatch(r"[\w./-]+", token) and token.endswith((".py", "/")):
            if not any((base / token).exists() for base in bases):
                stale.append(token)
        elif re.fullmatch(r"[a-z_]+(\.[A-Za-z_]\w*)+", token) and token.split(".")[0] in SUBPACKAGES:
            if not _resolves(f"histostudy.{token}"):
                stale.append(token)
    assert stale == [], f"docs/architecture.md names what does not exist: {sorted(set(stale))}"
