"""Frames rendered once and handed out again: inside a :func:`shared_frames` scope, a render with the same
inputs and Generator state returns a copy of the frame already made and leaves the Generator where the
first call left it."""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import hashlib
import pickle
from collections import OrderedDict
from collections.abc import Iterator

import numpy as np

__all__ = ["FrameMemo", "shared_frames"]


class FrameMemo:
    """The frames of one :func:`shared_frames` scope, the ``max_frames`` most recently used;
    ``hits`` and ``misses`` count the calls answered from it and rendered."""

    def __init__(self, max_frames: int = 32):
        if isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1:
            raise ValueError(f"max_frames must be an integer >= 1, got {max_frames!r}")
        self.max_frames = max_frames
        self.hits = 0
        self.misses = 0
        self._frames: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self._frames)

    def call(self, render, model, T_carm_transducer, view, *, rng, physical=None, background=None, **settings):
        """``render(model, T_carm_transducer, view, rng=rng, physical=physical, background=background,
        **settings)``, or the frame an identical earlier call made (module docstring)."""
        key = _key(model, T_carm_transducer, view, rng, physical, background, settings)
        if key is None:  # an input without a value to compare (an unpicklable background): render
            return render(model, T_carm_transducer, view, rng=rng, physical=physical, background=background,
                          **settings)
        entry = self._frames.get(key)
        if entry is not None and entry[0] is model and entry[1] is physical:
            self.hits += 1
            self._frames.move_to_end(key)
            rng.bit_generator.state = entry[3]
            return _copy(entry[2])
        self.misses += 1
        frame = render(model, T_carm_transducer, view, rng=rng, physical=physical, background=background, **settings)
        self._frames[key] = (model, physical, _copy(frame), rng.bit_generator.state)
        while len(self._frames) > self.max_frames:
            self._frames.popitem(last=False)
        return frame


_ACTIVE: contextvars.ContextVar[FrameMemo | None] = contextvars.ContextVar("histostudy_frame_memo", default=None)


@contextlib.contextmanager
def shared_frames(max_frames: int = 32) -> Iterator[FrameMemo]:
    """A scope in which :func:`~histostudy.imaging.render.render_frame` renders each distinct frame once.

    Scopes nest (the inner one answers) and are local to a thread or task (a context variable).

    Args:
        max_frames: how many frames the scope keeps (the most recently used).

    Yields:
        The scope's :class:`FrameMemo`.

    Raises:
        ValueError: ``max_frames`` is not an integer >= 1.
    """
    token = _ACTIVE.set(FrameMemo(max_frames))
    try:
        yield _ACTIVE.get()
    finally:
        _ACTIVE.reset(token)


def memoised_frames(render):
    """Decorate ``render`` (a function with ``render_frame``'s signature) so that it goes through
    the active :func:`shared_frames` scope, if any."""
    @functools.wraps(render)
    def wrapper(model, T_carm_transducer, view, *, rng, physical=None, background=None, **settings):
        memo = _ACTIVE.get()
        if memo is None or not isinstance(rng, np.random.Generator):
            return render(model, T_carm_transducer, view, rng=rng, physical=physical, background=background,
                          **settings)
        return memo.call(render, model, T_carm_transducer, view, rng=rng, physical=physical, background=background,
                         **settings)

    return wrapper


def _digest(value) -> str | None:
    if value is None:
        return "none"
    if isinstance(value, np.ndarray):
        return f"array:{value.dtype}:{value.shape}:{hashlib.blake2b(np.ascontiguousarray(value).tobytes()).hexdigest()}"
    try:
        return "pickle:" + hashlib.blake2b(pickle.dumps(value, protocol=4)).hexdigest()
    except Exception:  # noqa: BLE001 - any object pickle refuses has no value to compare
        return None


def _key(model, T, view, rng, physical, background, settings) -> tuple | None:
    scene = _digest(background)
    if scene is None or not hasattr(view, "P"):
        return None
    return (id(model), id(physical), np.asarray(T, np.float64).tobytes(), np.asarray(view.P, np.float64).tobytes(),
            tuple(view.shape), float(view.pixel_mm), view.name, scene, repr(rng.bit_generator.state),
            repr(sorted(settings.items())))


def _copy(frame):
    return dataclasses.replace(frame, image=frame.image.copy(),
                               labels=None if frame.labels is None else frame.labels.copy(),
                               meta=dict(frame.meta))
