"""Random-number plumbing: every random draw in the package takes a seed or a Generator.

See docs/architecture.md, Seeding and determinism.
"""

from __future__ import annotations

import numpy as np

__all__ = ["as_generator"]


def as_generator(rng) -> np.random.Generator:
    """A Generator from a seed (int) or a Generator; anything else raises TypeError naming ``rng``."""
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng must be a numpy.random.Generator or an int seed, got {type(rng).__name__}: {rng!r}")
