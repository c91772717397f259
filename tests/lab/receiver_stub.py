"""What the receiver's fast tests share (tests/lab/test_receiver_*.py): a stub tracker instead of
the learned stages, small biplane views, a pair of small single-frame XA objects per instant, a
receiver made with the stub, the pose lines written, a free TCP port."""

import datetime as dt
import json
import socket
import threading
from types import SimpleNamespace

import numpy as np

from histostudy.imaging import default_biplane, xa_dataset
from histostudy.lab import FrameReceiver

T0 = dt.datetime(2024, 5, 6, 10, 30, 0)
INTERVAL_S = 0.1  # between pairs: more than the pairing's tolerance, so each pair is its own


class StubTracker:
    """What the receiver asks of a Tracker (``track``, ``stats``, ``last_kind``), without pose work:
    each pair's result has a focal point of (index, mean of the first image, mean of the second)
    (index from 1; the means tell the pixels received). With ``hold``, the first pair is held until
    ``release`` is set (``taken`` is set once it is)."""

    def __init__(self, hold: bool = False):
        self.hold, self.taken, self.release = hold, threading.Event(), threading.Event()
        self.images, self.last_kind = [], None

    def stats(self) -> dict:
        return {"stage_seconds": {}, "n_updates": len(self.images)}

    def track(self, pairs, *, ready=None):
        for images in pairs:
            self.images.append(images)
            self.taken.set()
            if self.hold and len(self.images) == 1:
                assert self.release.wait(30)
            self.last_kind = "from_scratch" if len(self.images) == 1 else "warm"
            verdict = SimpleNamespace(ok=True, reasons=[], rms_distance_px=[1.0, 1.0],
                                      view_disagreement_mm=[0.1, 0.1], unexplained_fraction=[0.0, 0.0])
            focal = np.array([len(self.images), *(float(np.mean(image)) for image in images[:2])])
            yield SimpleNamespace(T_carm_transducer=np.eye(4), focal_point_mm=focal, cost=0.0, verdict=verdict,
                                  timings_s={"total": 0.0})


def small_views():
    """The paper's biplane on a small detector: fast to send and decode."""
    return default_biplane(shape=(48, 62), pixel_mm=6.16)


def pair_objects(views, k: int, blank: bool = False) -> list:
    """Pair ``k``: one single-frame XA object per plane, taken ``k`` intervals after T0."""
    rng = np.random.default_rng(k)
    objects = []
    for view in views:
        counts = rng.integers(100, 4000, size=view.shape).astype(np.uint16)
        ds = xa_dataset(view, counts, acquisition_time=T0 + dt.timedelta(seconds=k * INTERVAL_S),
                        uid_seed=f"pair{k}/{view.name}/{blank}")
        if blank:
            ds.PixelData = bytes(len(ds.PixelData))
        objects.append(ds)
    return objects


def receiver_with(views, tmp_path, tracker, **options) -> FrameReceiver:
    """A receiver on a free loopback port writing ``tmp_path/poses.jsonl``, its tracker ``tracker``."""
    receiver = FrameReceiver(views, output_path=tmp_path / "poses.jsonl", port=0, tolerance_s=0.02, **options)
    receiver.tracker = tracker
    return receiver


def read_lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def free_port() -> int:
    """A TCP port nothing listens on (bound, then closed)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
