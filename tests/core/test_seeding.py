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
