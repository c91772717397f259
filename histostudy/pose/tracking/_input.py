"""The frame pairs a :class:`~._tracker.Tracker` accepts (§II-A): :func:`frames_for_views` checks them
against the tracker's views and wraps arrays as :class:`~histostudy.imaging.Frame` (line integrals,
``-log(I / I0)``, on each view's detector grid).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from histostudy.imaging import Frame, View

__all__ = ["frames_for_views"]


def frames_for_views(frames, views: Sequence[View]) -> list[Frame]:
    """``frames`` as one :class:`~histostudy.imaging.Frame` per view of ``views``, in order, or a
    ValueError naming the bad one: what :meth:`~._tracker.Tracker.update` accepts (Frames taken with
    those views, 2-D arrays of line integrals of each view's shape, or a ``(n_views, rows, cols)``
    array)."""
    names = ", ".join(repr(v.name) for v in views)
    if isinstance(frames, Frame) or (isinstance(frames, np.ndarray) and frames.ndim < 3) \
            or isinstance(frames, (str, bytes)):
        raise ValueError(f"frames must be a sequence of one frame per view ({len(views)}: {names}), "
                         f"got a single {type(frames).__name__}")
    try:
        frames = list(frames)
    except TypeError:
        raise ValueError(f"frames must be a sequence of one frame per view ({len(views)}: {names}), "
                         f"got {type(frames).__name__}") from None
    if len(frames) != len(views):
        raise ValueError(f"frames must hold one frame per view, {len(views)} ({names}), got {len(frames)}")
    out = []
    for i, (f, view) in enumerate(zip(frames, views)):
        if isinstance(f, Frame):
            if f.shape != view.shape or not _same_projection(f.view, view):
                raise ValueError(f"frames[{i}] was taken with view {f.view!r}, not with views[{i}] = {view!r} "
                                 "(the tracker's views, in order)")
            out.append(f)
            continue
        image = np.asarray(f)
        if image.ndim != 2 or not np.issubdtype(image.dtype, np.number):
            raise ValueError(f"frames[{i}] must be a Frame or a 2-D numeric array of line integrals of view "
                             f"{view.name!r}'s shape {view.shape}, got shape {image.shape} dtype {image.dtype}")
        if image.shape != view.shape:
            raise ValueError(f"frames[{i}] has shape {image.shape}; view {view.name!r} (views[{i}]) expects "
                             f"{view.shape}")
        try:
            out.append(Frame(image, view))
        except ValueError as exc:
            raise ValueError(f"frames[{i}]: {exc}") from None
    return out


def _same_projection(a: View, b: View) -> bool:
    """True when two views' 3x4 matrices agree up to their (positive) scale."""
    Pa, Pb = a.P / np.linalg.norm(a.P), b.P / np.linalg.norm(b.P)
    return bool(np.allclose(Pa, Pb, rtol=0.0, atol=1e-9))
