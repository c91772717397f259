"""The package's layering (docs/architecture.md, "Layers"): imports go one way, between subpackages
and inside ``study`` and ``pose``, there are no import cycles, no package imports another's private
module, and each package's ``__all__`` is a short, hand-written list of what its callers use."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

import histostudy

PACKAGE = Path(histostudy.__file__).parent
REPO = PACKAGE.parent

#: Rank of each subpackage: a module imports only from a lower rank or from its own subpackage.
LAYERS = {
    "core": 0,
    "geometry": 1,
    "transducer": 2,
    "imaging": 3,
    "learning": 4,
    "pose": 5,
    "calibration": 6,
    "robot": 6,
    "treatment": 7,
    "lab": 8,
    "study": 9,
    "reporting": 10,
    "cli": 11,
}

#: Module paths removed in 0.2.0 and 0.3.0 (CHANGELOG.md, "Removed"): a sample of each release's.
REMOVED = ("histostudy.carm", "histostudy.frame", "histostudy.render", "histostudy.anatomy", "histostudy.volume_io",
           "histostudy.segment", "histostudy.orientation", "histostudy.handeye", "histostudy.stats",
           "histostudy.core.moved_modules", "histostudy.study.targeting_setup", "histostudy.imaging.anatomy_params",
           "histostudy.learning.training_config", "histostudy.pose.tracker", "histostudy.study.error_budget")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path) -> set[str]:
    """Every histostudy module that ``name`` imports, at module level or inside a function."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("histostudy"):
                found.add(target)
                found.update(f"{target}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("histostudy"))
    return found


MODULES = _modules()
GRAPH = {name: {m for m in _imports(name, path) if m in MODULES and m != name} for name, path in MODULES.items()}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_sits_in_a_layer():
    loose = sorted(m for m in MODULES if m != "histostudy" and _layer(m) is None)
    assert loose == [], f"modules outside the layers {sorted(LAYERS)}: {loose}"


def test_imports_go_one_way():
    wrong = []
    for module, targets in GRAPH.items():
        layer = _layer(module)
        if layer is None:
            continue
        for target in targets:
            other = _layer(target)
            if other is not None and other != layer and LAYERS[other] >= LAYERS[layer]:
                wrong.append(f"{module} -> {target}")
    assert wrong == [], "imports against the layering:\n" + "\n".join(sorted(wrong))


def test_no_import_cycles():
    # a subpackage's __init__ re-exports its modules; an edge into it stands for the modules it names
    def edges(module):
        return {t for t in GRAPH[module] if not (module.startswith(t + ".") and MODULES[t].name == "__init__.py")}

    state, stack, cycles = {}, [], []

    def visit(module):
        state[module] = "open"
        stack.append(module)
        for target in sorted(edges(module)):
            if state.get(target) == "open":
                cycles.append(stack[stack.index(target):] + [target])
            elif target not in state:
                visit(target)
        stack.pop()
        state[module] = "done"

    for module in sorted(GRAPH):
        if module not in state:
            visit(module)
    assert cycles == [], "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


@pytest.mark.parametrize("old", REMOVED)
def test_the_removed_module_paths_no_longer_import(old):
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


def test_importing_the_package_installs_no_import_hook():
    import subprocess
    import sys

    code = "import sys; n = len(sys.meta_path); import histostudy; print(len(sys.meta_path) - n)"
    added = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert added.strip() == "0"


def _private_owner(target: str) -> str | None:
    """The package whose private module (or private name) ``target`` is, or None where it is public."""
    parts = target.split(".")
    for i, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            owner = ".".join(parts[:i])
            # a private name of a module is its package's
            if owner in MODULES and MODULES[owner].name != "__init__.py":
                owner = owner.rsplit(".", 1)[0]
            return owner
    return None


def test_no_package_imports_another_package_s_private_module():
    """A package's ``_private`` modules are its own: another package imports the name from the
    package's public ``__init__`` or a public module (docs/architecture.md, "Layers")."""
    wrong = []
    for module, path in MODULES.items():
        package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
        for target in _imports(module, path):
            owner = _private_owner(target)
            if owner is not None and not (package == owner or package.startswith(owner + ".")):
                wrong.append(f"{module} -> {target}")
    assert wrong == [], "imports of another package's private module:\n" + "\n".join(sorted(set(wrong)))


#: The most names a package's ``__all__`` lists: what callers use, not every public name of its modules.
MAX_EXPORTS = 40


@pytest.mark.parametrize("package", sorted(m for m, p in MODULES.items() if p.name == "__init__.py"))
def test_each_package_exports_a_short_hand_written_list(package):
    module = importlib.import_module(package)
    exported = list(getattr(module, "__all__", ()))
    assert len(exported) <= MAX_EXPORTS, f"{package}.__all__ has {len(exported)} names"
    assert len(set(exported)) == len(exported), f"{package}.__all__ names a name twice"
    missing = [n for n in exported if not hasattr(module, n)]
    assert missing == [], f"{package}.__all__ names what it does not import: {missing}"
    assert all(not n.startswith("_") for n in exported)


#: Rank of each unit (module or sub-package) of ``histostudy.study``: a unit imports only units of a
#: lower rank. The section interface and statistics first; what notebooks 02 and 03 share; the
#: sections of the learned stages; pose (04) and the learned stages' training campaigns on them, then
#: targeting (05) on pose; the error budget (07) and the lab's data (06) on both.
STUDY_LAYERS = {
    "section": 0, "stats": 0,
    "held_out": 1, "projections": 1,
    "segmentation": 2, "orientation": 2,
    "pose": 3, "campaign": 3,
    "targeting": 4,
    "budget": 5, "your_data": 5,
}


#: The same for ``histostudy.pose``: eq. 3's ingredients, the cost, the options, the truncated costs
#: and the refinement, the initialisation and verdict on them, then the stages' composition
#: (``from_labels``, ``estimate``) and what is built on it (the pose from files, the tracker).
POSE_LAYERS = {
    "distance_maps": 0, "perturbation": 0, "conic": 0, "init": 0, "estimate_memo": 0,
    "cost": 1, "silhouette": 1, "directions": 1,
    "options": 2,
    "truncations": 3,
    "refine": 4,
    "conic_orientation": 5, "start": 5, "verdict": 5,
    "result": 6, "retries": 6, "learned_stages": 6,
    "labels": 7,
    "from_labels": 8,
    "estimate": 9,
    "from_files": 10, "tracking": 10,
}


def _unit(module: str, package: str) -> str | None:
    rest = module[len(package) + 1:].split(".") if module.startswith(package + ".") else None
    return rest[0] if rest else None


@pytest.mark.parametrize("package, ranks", [("histostudy.study", STUDY_LAYERS), ("histostudy.pose", POSE_LAYERS)])
def test_imports_go_one_way_inside_a_package(package, ranks):
    units = {_unit(m, package) for m in MODULES} - {None}
    assert units == set(ranks), f"units of {package} without a rank, or ranks without a unit"
    wrong = []
    for module, targets in GRAPH.items():
        unit = _unit(module, package)
        for target in targets:
            other = _unit(target, package)
            if unit and other and other != unit and ranks[other] >= ranks[unit]:
                wrong.append(f"{module} -> {target}")
    assert wrong == [], f"imports against {package}'s layering:\n" + "\n".join(sorted(wrong))
