"""Work shared between runs of one experiment whose frames are alike (the budget's configurations,
the labs): a frame rendered, segmented and estimated once per distinct input and Generator state,
the Generator left where the first call left it, so every run gets its own numbers (exact).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator

from histostudy.core import GeneratorMemo
from histostudy.imaging import shared_frames
from histostudy.pose import shared_estimates

from ..pose.segmentations import SegmentationCache

__all__ = ["SharedWork", "shared_work"]


@dataclasses.dataclass(frozen=True)
class SharedWork:
    """What a :func:`shared_work` scope shares: its frames (the memo of :func:`~histostudy.imaging.shared_frames`),
    segmentations (a :class:`~histostudy.study.pose.segmentations.SegmentationCache`) and estimates
    (the memo of :func:`~histostudy.pose.shared_estimates`), each counting its ``hits`` and ``misses``."""

    frames: GeneratorMemo
    segmentations: SegmentationCache
    estimates: GeneratorMemo


@contextlib.contextmanager
def shared_work(setup, config, *, max_frames: int = 32) -> Iterator[tuple]:
    """A scope for the runs of one experiment: yields ``(setup', shared)``, the set-up (a
    :class:`~._run.BudgetSetup`) with its segmenter (``config.segmenter()`` where it has none, as the
    studies default) wrapped in a :class:`~histostudy.study.pose.segmentations.SegmentationCache`,
    and the :class:`SharedWork`; ``max_frames`` bounds each of the three."""
    segmenter = setup.segmenter if setup.segmenter is not None else config.segmenter()
    segmentations = SegmentationCache(segmenter, max_frames)
    with shared_frames(max_frames) as frames, shared_estimates(max_frames) as estimates:
        yield dataclasses.replace(setup, segmenter=segmentations), SharedWork(frames, segmentations, estimates)
