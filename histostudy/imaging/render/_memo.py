"""Frames rendered once and handed out again: inside a :func:`shared_frames` scope, a render with the same
inputs and Generator state returns a copy of the frame already made and leaves the Generator where the
first call left it."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Iterator

import numpy as np

from histostudy.core import GeneratorMemo, MemoScope, check_count, value_digest

__all__ = ["shared_frames"]

_FRAMES = MemoScope("histostudy_shared_frames")


@contextlib.contextmanager
def shared_frames(max_frames: int = 32) -> Iterator[GeneratorMemo]:
    """A scope in which :func:`~histostudy.imaging.render.render_frame` renders each distinct frame once.

    A render is the same as an earlier one when its pose, view, background, settings and Generator
    state are equal and its model and physical transducer are the same objects; a render given an
    int seed or None is always made. Scopes nest (the inner one answers) and are local to a thread
    or task (a context variable).

    Args:
        max_frames: how many frames the scope keeps (the most recently used).

    Yields:
        The scope's :class:`~histostudy.core.GeneratorMemo` (its ``hits`` and ``misses``).

    Raises:
        ValueError: ``max_frames`` is not an integer >= 1.
    """
    with _FRAMES.open(GeneratorMemo(check_count(max_frames, "max_frames"))) as memo:
        yield memo


def memoised_frames(render):
    """Decorate ``render`` (a function with ``render_frame``'s signature) so that it goes through
    the active :func:`shared_frames` scope, if any."""
    @functools.wraps(render)
    def wrapper(model, T_carm_transducer, view, *, rng, physical=None, background=None, **settings):
        def compute():
            return render(model, T_carm_transducer, view, rng=rng, physical=physical, background=background,
                          **settings)

        memo = _FRAMES.active()
        if memo is None or not isinstance(rng, np.random.Generator):
            return compute()
        key = value_digest((np.asarray(T_carm_transducer, np.float64), view, background, settings))
        if key is None:  # an input without a value to compare (an unpicklable background): render
            return compute()
        return memo.call(key, compute, rng=rng, holders=(model, physical), copy_result=_copy)

    return wrapper


def _copy(frame):
    return dataclasses.replace(frame, image=frame.image.copy(),
                               labels=None if frame.labels is None else frame.labels.copy(),
                               meta=dict(frame.meta))
