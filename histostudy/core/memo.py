"""Results computed once and handed out again, exact for computations that draw from a numpy
Generator: a :class:`GeneratorMemo` keyed by :func:`value_digest`, opened for a block of code by a
:class:`MemoScope` (the frames of ``imaging.shared_frames``, the estimates of ``pose.shared_estimates``,
the labels of ``study.pose.segmentations.SegmentationCache``).
"""

from __future__ import annotations

import contextlib
import contextvars
import copy
import dataclasses
import hashlib
import pickle
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator

import numpy as np

from .checks import check_count

__all__ = ["GeneratorMemo", "MemoScope", "value_digest"]


class GeneratorMemo:
    """The ``max_entries`` most recently used results of a computation, each stored with the state
    its Generator was left in, so that a repeat is indistinguishable from computing again.

    ``hits`` and ``misses`` count the calls answered from the memo and computed. Safe to share
    between threads: two threads asking for the same key at once may both compute it (the same
    result, the second stored over the first).

    Args:
        max_entries: how many results are kept, an integer >= 1.

    Raises:
        ValueError: ``max_entries`` is not an integer >= 1.
    """

    def __init__(self, max_entries: int = 32):
        self.max_entries = check_count(max_entries, "max_entries")
        self.hits = 0
        self.misses = 0
        self._entries: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def call(self, key: Hashable, compute: Callable[[], object], *, rng: np.random.Generator | None = None,
             holders: tuple = (), copy_result: Callable[[object], object] = copy.deepcopy,
             remember_errors: bool = False):
        """``compute()``, or what an earlier call with an equal ``key`` and the same ``holders`` gave.

        Args:
            key: the value of every input ``compute`` reads besides ``holders`` and ``rng``'s state
                (:func:`value_digest` makes one); the Generator's state is added here.
            compute: the computation, called with no arguments.
            rng: the Generator ``compute`` draws from, or None where it draws nothing. A repeat sets
                it to the state the first call left it in.
            holders: objects ``compute`` reads that compare by identity (a model, a segmenter):
                an entry answers only a call with the very same objects, and keeps them alive so
                that their ids are not reused.
            copy_result: how a stored result is copied, going in and coming out, so that no caller
                holds the memo's own.
            remember_errors: also store an ``Exception`` ``compute`` raised and raise a copy of it
                again on a repeat (a refusal is a result); otherwise an error is never stored.

        Returns:
            What ``compute()`` returned, or a copy of what it returned for the equal call.
        """
        full_key = (key, repr(rng.bit_generator.state) if rng is not None else None, tuple(map(id, holders)))
        with self._lock:
            entry = self._entries.get(full_key)
            if entry is not None and _same(entry[0], holders):
                self.hits += 1
                self._entries.move_to_end(full_key)
            else:
                entry = None
                self.misses += 1
        if entry is not None:
            _, raised, value, state = entry
            if rng is not None:
                rng.bit_generator.state = state
            if raised:
                raise copy.copy(value)
            return copy_result(value)
        try:
            result = compute()
        except Exception as exc:
            if remember_errors:
                self._store(full_key, (holders, True, copy.copy(exc), _state(rng)))
            raise
        self._store(full_key, (holders, False, copy_result(result), _state(rng)))
        return result

    def _store(self, key, entry) -> None:
        with self._lock:
            self._entries[key] = entry
            while len(self._entries) > self.max_entries:
                self._entries.popitem(last=False)


def _same(stored: tuple, holders: tuple) -> bool:
    return len(stored) == len(holders) and all(a is b for a, b in zip(stored, holders))


def _state(rng: np.random.Generator | None):
    return None if rng is None else rng.bit_generator.state


class MemoScope:
    """A named, context-local slot for one kind of memo: :meth:`open` makes a memo the active one
    for a block, :meth:`active` returns it (None outside every block).

    Blocks nest (the innermost answers) and are local to a thread or asyncio task (a
    :class:`contextvars.ContextVar`).

    Args:
        name: the context variable's name, for debugging.
    """

    def __init__(self, name: str):
        self._active: contextvars.ContextVar = contextvars.ContextVar(name, default=None)

    @contextlib.contextmanager
    def open(self, memo) -> Iterator:
        """Make ``memo`` the active one for the block.

        Args:
            memo: any object, most often a :class:`GeneratorMemo`.

        Yields:
            ``memo``.
        """
        token = self._active.set(memo)
        try:
            yield memo
        finally:
            self._active.reset(token)

    def active(self):
        """The memo of the innermost open block, or None."""
        return self._active.get()


def value_digest(value) -> str | None:
    """A digest of ``value``'s content: equal digests for equal values, of the same types.

    Arrays are read by dtype, shape and bytes; dataclasses field by field; mappings, lists and
    tuples item by item; numbers, strings and bytes by type and ``repr``; anything else through
    ``pickle``.

    Args:
        value: the value; any nesting of the above.

    Returns:
        A hex digest, or None where some part of ``value`` has no content to compare (``pickle``
        refuses it): such a value must be computed afresh.
    """
    hasher = hashlib.blake2b(digest_size=20)
    try:
        _feed(hasher, value)
    except _NoContent:
        return None
    return hasher.hexdigest()


class _NoContent(Exception):
    pass


_SCALARS = (bool, int, float, complex, str, bytes, np.generic)


def _feed(hasher, value) -> None:
    if value is None:
        hasher.update(b"N;")
    elif isinstance(value, np.ndarray):
        hasher.update(f"A{value.dtype.str}{value.shape};".encode())
        hasher.update(np.ascontiguousarray(value).tobytes() if value.dtype != object else _pickled(value))
    elif isinstance(value, _SCALARS):
        hasher.update(f"S{type(value).__qualname__}:{value!r};".encode())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        hasher.update(f"D{type(value).__module__}.{type(value).__qualname__}(".encode())
        for field in dataclasses.fields(value):
            hasher.update(field.name.encode() + b"=")
            _feed(hasher, getattr(value, field.name))
        hasher.update(b");")
    elif isinstance(value, dict):
        hasher.update(f"M{len(value)}(".encode())
        for k, v in sorted(value.items(), key=lambda item: repr(item[0])):
            _feed(hasher, k)
            _feed(hasher, v)
        hasher.update(b");")
    elif isinstance(value, (list, tuple)):
        hasher.update(f"{type(value).__qualname__}{len(value)}(".encode())
        for item in value:
            _feed(hasher, item)
        hasher.update(b");")
    else:
        hasher.update(f"P{type(value).__module__}.{type(value).__qualname__}:".encode() + _pickled(value))


def _pickled(value) -> bytes:
    try:
        return pickle.dumps(value, protocol=5)
    except Exception as exc:  # noqa: BLE001 - any object pickle refuses has no content to compare
        raise _NoContent from exc
