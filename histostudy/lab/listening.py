"""``histostudy listen``'s loop (§II-A): :func:`listen`, a :class:`.receiver.FrameReceiver` started,
served until Ctrl-C, a number of pose lines or a time-out, and its statistics returned.
"""

from __future__ import annotations

import os
from typing import Callable, Sequence

from histostudy.imaging import View
from histostudy.transducer import TransducerModel
from .receiver import FrameReceiver

__all__ = ["listen"]


def listen(views: Sequence[View], *, port: int = 11112, output_path: str | os.PathLike = "poses.jsonl",
           host: str = "127.0.0.1", ae_title: str = "HISTOSTUDY", max_pairs: int | None = None,
           timeout_s: float | None = None, model: TransducerModel | None = None, seed=0,
           on_pose: Callable[[dict], object] | None = None, on_start: Callable[[int], object] | None = None,
           **receiver_options) -> dict:
    """Receive live C-arm frames and write a pose per biplane pair until Ctrl-C, ``max_pairs`` lines
    or ``timeout_s`` seconds (what ``histostudy listen`` runs); returns :meth:`FrameReceiver.stats`.

    ``on_start(port)`` is called once listening (the bound port, useful with ``port=0``); the
    other arguments are :class:`FrameReceiver`'s.
    """
    receiver = FrameReceiver(views, model, output_path=output_path, ae_title=ae_title, port=port, host=host,
                             seed=seed, on_pose=on_pose, **receiver_options)
    bound = receiver.start()
    if on_start is not None:
        try:
            on_start(bound)
        except BaseException:
            receiver.stop(drain=False)
            raise
    try:
        return receiver.serve_forever(max_pairs=max_pairs, timeout_s=timeout_s)
    finally:
        # serve_forever stops the receiver once it serves; a bad max_pairs or timeout_s raises before
        # that, and the receiver started above must not be left listening with its worker running
        receiver.stop(drain=False)
