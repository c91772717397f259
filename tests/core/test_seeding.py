"""histostudy.core.seeding: one seed/Generator policy for the package."""

import numpy as np
import pytest

from histostudy.core import as_generator


def test_a_generator_passes_through_and_a_seed_makes_a_reproducible_one():
    g = np.random.default_rng(3)
    assert as_generator(g) is g
    assert as_generator(7).random() == np.random.default_rng(7).random()
    assert as_generator(np.int64(7)).random() == np.random.default_rng(7).random()


@pytest.mark.parametrize("bad", [True, 1.5, "3", None, np.random.RandomState(0)])
def test_anything_else_is_refused_naming_the_argument(bad):
    with pytest.raises(TypeError, match="rng must be a numpy.random.Generator or an int seed"):
        as_generator(bad)


def test_no_module_of_the_package_draws_from_an_unseeded_or_global_generator():
    """The seeding rule (docs/architecture.md, "Seeding and determinism"): no ``default_rng()``
    without a seed, no numpy legacy global state, no stdlib ``random``."""
    import ast
    from pathlib import Path

    import histostudy

    legacy = {"rand", "randn", "random", "random_sample", "seed", "choice", "normal", "uniform", "randint",
              "shuffle", "permutation", "standard_normal"}
    found = []
    for path in sorted(Path(histostudy.__file__).parent.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            where = f"{path.name}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Call):
                func = node.func
                name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
                if name == "default_rng" and not node.args and not node.keywords:
                    found.append(f"{where} default_rng()")
                if (isinstance(func, ast.Attribute) and func.attr in legacy and isinstance(func.value, ast.Attribute)
                        and func.value.attr == "random" and getattr(func.value.value, "id", "") in ("np", "numpy")):
                    found.append(f"{where} np.random.{func.attr}")
            elif isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                found += [f"{where} import random" for n in names if n == "random"]
    assert found == []
