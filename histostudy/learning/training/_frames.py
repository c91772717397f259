"""The frames a training run trains and validates on, rendered into the frame cache beforehand in
worker processes (:func:`prerender_run`), so that the run's own loop finds them cached."""

from __future__ import annotations

from pathlib import Path

from histostudy.core import check_count

from ..datasets import HybridFrames
from ._config import TrainingConfig, run_frame_sets

__all__ = ["prerender_run"]


def prerender_run(cfg: TrainingConfig, seed: int, *, cache_dir: str | Path, workers: int = 1) -> int:
    """Render the frames of every stage of a run that the cache lacks (validation first, then training).

    The frames are the ones the run's loop would render itself (:meth:`HybridFrames.prerender`), so
    the run computes the same with or without this; only the wall time differs.

    Args:
        cfg: the run's configuration (its stages' frame sets: :func:`run_frame_sets`).
        seed: the run's seed (the frames' seeds derive from it).
        cache_dir: the frame cache the run reads.
        workers: processes that render (1: in this process).

    Returns:
        How many frames were rendered.

    Raises:
        ValueError: ``seed`` negative or ``workers`` below 1.
    """
    check_count(seed, "seed", minimum=0)
    check_count(workers, "workers")
    return sum(HybridFrames(split, seed, config=render, cache_dir=cache_dir).prerender(n, workers=workers)
               for render, n_train, n_val in run_frame_sets(cfg)
               for split, n in (("val", n_val), ("train", n_train)))
