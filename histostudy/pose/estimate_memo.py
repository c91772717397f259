"""Estimates made once and handed out again: inside a :func:`shared_estimates` scope, an
:func:`~histostudy.pose.estimate_pose` call with the same frames, stages, options and Generator state
as an earlier one returns a copy of that result (or raises its refusal again) and leaves the
Generator where the first call left it, so that the numbers are those of a second estimate.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Iterator

import numpy as np

from histostudy.core import GeneratorMemo, MemoScope, check_count, value_digest

__all__ = ["shared_estimates"]

_ESTIMATES = MemoScope("histostudy_shared_estimates")


@contextlib.contextmanager
def shared_estimates(max_estimates: int = 64) -> Iterator[GeneratorMemo]:
    """A scope in which :func:`~histostudy.pose.estimate_pose` estimates each distinct call once.

    A call is the same as an earlier one when its frames (images, labels, views, poses, meta), its
    options and keyword overrides, its initial pose and its Generator's state are equal and its model,
    segmenter and orientation source are the same objects; a call with an int seed or None is
    always estimated. Exact for stages whose output depends only on their inputs and the Generator
    passed (the library's all do). A result handed out again keeps the first call's ``timings_s``.
    Scopes nest (the inner one answers) and are local to a thread or task (a context variable).

    Args:
        max_estimates: how many estimates the scope keeps (the most recently used).

    Yields:
        The scope's :class:`~histostudy.core.GeneratorMemo` (its ``hits`` and ``misses``).

    Raises:
        ValueError: ``max_estimates`` is not an integer >= 1.
    """
    with _ESTIMATES.open(GeneratorMemo(check_count(max_estimates, "max_estimates"))) as memo:
        yield memo


def memoised_estimates(estimate):
    """Decorate ``estimate`` (a function with ``estimate_pose``'s signature) so that it goes
    through the active :func:`shared_estimates` scope, if any."""

    @functools.wraps(estimate)
    def wrapper(frames, model, *, segmenter=None, orientation=None, rng=None, initial_pose=None, options=None,
                **option_overrides):
        given = frames if isinstance(frames, (list, tuple)) else list(frames)  # read twice below

        def compute():
            return estimate(given, model, segmenter=segmenter, orientation=orientation, rng=rng,
                            initial_pose=initial_pose, options=options, **option_overrides)

        memo = _ESTIMATES.active()
        if memo is None or not isinstance(rng, np.random.Generator):
            return compute()
        pose = None if initial_pose is None else np.asarray(initial_pose, dtype=np.float64)
        key = value_digest((list(given), pose, options, option_overrides))
        if key is None:  # an input without a value to compare: estimate
            return compute()
        return memo.call(key, compute, rng=rng, holders=(model, segmenter, orientation), remember_errors=True)

    return wrapper
