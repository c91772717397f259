"""Random-number plumbing: every random draw in the package takes a seed or a Generator (see
docs/architecture.md, "Seeding and determinism")."""

from __future__ import annotations

import numpy as np

__all__ = ["as_generator"]


def as_generator(rng) -> np.random.Generator:
    """The random generator of a seed or a generator.

    Args:
        rng: an int seed (Python or numpy, not bool) or a ``numpy.random.Generator``.

    Returns:
        ``rng`` itself if a Generator, else ``numpy.random.default_rng(rng)``.

    Raises:
        TypeError: ``rng`` is neither; the message names ``rng``.
    """
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng must be a numpy.random.Generator or an int seed, got {type(rng).__name__}: {rng!r}")
