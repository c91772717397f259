"""Estimates made once and handed out again: inside a :func:`shared_estimates` scope, an
:func:`~histostudy.pose.estimate_pose` call with the same frames, stages, options and Generator state
as an earlier one returns a copy of that result (or raises its refusal again) and leaves the
Generator where the first call left it, so that the numbers are those of a second estimate.
"""

from __future__ import annotations

import contextlib
import contextvars
import copy
import functools
import hashlib
import pickle
from collections import OrderedDict
from collections.abc import Iterator

import numpy as np

__all__ = ["EstimateMemo", "shared_estimates"]


class EstimateMemo:
    """The estimates of one :func:`shared_estimates` scope, the ``max_estimates`` most recently
    used; ``hits`` and ``misses`` count the calls answered from it and estimated.

    Args:
        max_estimates: how many estimates the scope keeps, an integer >= 1.

    Raises:
        ValueError: ``max_estimates`` is not an integer >= 1.
    """

    def __init__(self, max_estimates: int = 64):
        if isinstance(max_estimates, bool) or not isinstance(max_estimates, int) or max_estimates < 1:
            raise ValueError(f"max_estimates must be an integer >= 1, got {max_estimates!r}")
        self.max_estimates = max_estimates
        self.hits = 0
        self.misses = 0
        self._entries: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self._entries)

    def call(self, estimate, frames, model, *, segmenter, orientation, rng, initial_pose, options, overrides):
        """``estimate(frames, model, ...)``, or what an identical earlier call gave (module docstring)."""
        key = _key(frames, model, segmenter, orientation, rng, initial_pose, options, overrides)
        kwargs = dict(segmenter=segmenter, orientation=orientation, rng=rng, initial_pose=initial_pose,
                      options=options, **overrides)
        if key is None:  # an input without a value to compare: estimate
            return estimate(frames, model, **kwargs)
        entry = self._entries.get(key)
        # the stages are compared by identity: the entry holds them, so their ids stay theirs
        if entry is not None and entry[0] == (model, segmenter, orientation):
            self.hits += 1
            self._entries.move_to_end(key)
            rng.bit_generator.state = entry[3]
            if entry[1] == "raised":
                raise copy.copy(entry[2])
            return copy.deepcopy(entry[2])
        self.misses += 1
        try:
            result = estimate(frames, model, **kwargs)
        except Exception as exc:
            self._store(key, (model, segmenter, orientation), "raised", copy.copy(exc), rng)
            raise
        self._store(key, (model, segmenter, orientation), "returned", copy.deepcopy(result), rng)
        return result

    def _store(self, key, stages, outcome, value, rng) -> None:
        self._entries[key] = (_Identity(stages), outcome, value, rng.bit_generator.state)
        while len(self._entries) > self.max_estimates:
            self._entries.popitem(last=False)


class _Identity(tuple):
    """A tuple compared element by element with ``is``: stages compare by identity, not value."""

    def __eq__(self, other):
        return len(self) == len(other) and all(a is b for a, b in zip(self, other))

    __hash__ = tuple.__hash__


_ACTIVE: contextvars.ContextVar[EstimateMemo | None] = contextvars.ContextVar("histostudy_estimate_memo",
                                                                             default=None)


@contextlib.contextmanager
def shared_estimates(max_estimates: int = 64) -> Iterator[EstimateMemo]:
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
        The scope's :class:`EstimateMemo`.

    Raises:
        ValueError: ``max_estimates`` is not an integer >= 1.
    """
    token = _ACTIVE.set(EstimateMemo(max_estimates))
    try:
        yield _ACTIVE.get()
    finally:
        _ACTIVE.reset(token)


def memoised_estimates(estimate):
    """Decorate ``estimate`` (a function with ``estimate_pose``'s signature) so that it goes
    through the active :func:`shared_estimates` scope, if any."""

    @functools.wraps(estimate)
    def wrapper(frames, model, *, segmenter=None, orientation=None, rng=None, initial_pose=None, options=None,
                **option_overrides):
        memo = _ACTIVE.get()
        if memo is None or not isinstance(rng, np.random.Generator):
            return estimate(frames, model, segmenter=segmenter, orientation=orientation, rng=rng,
                            initial_pose=initial_pose, options=options, **option_overrides)
        return memo.call(estimate, frames, model, segmenter=segmenter, orientation=orientation, rng=rng,
                         initial_pose=initial_pose, options=options, overrides=option_overrides)

    return wrapper


def _key(frames, model, segmenter, orientation, rng, initial_pose, options, overrides) -> tuple | None:
    digest = hashlib.blake2b()
    try:
        for frame in frames:
            digest.update(pickle.dumps(frame, protocol=5))
        digest.update(pickle.dumps((options, sorted(overrides.items())), protocol=5))
    except Exception:  # noqa: BLE001 - an input pickle refuses has no value to compare
        return None
    pose = None if initial_pose is None else np.asarray(initial_pose, dtype=np.float64).tobytes()
    return (id(model), id(segmenter), id(orientation), digest.hexdigest(), pose, repr(rng.bit_generator.state))
