"""histostudy.lab.stream_frames: objects stored at the pace of their acquisition times, as a C-arm
streams a fluoroscopy run (§II-A), to a bare Storage SCP on loopback that records when each arrives."""

import copy
import datetime as dt
import time

import numpy as np
import pytest
from pynetdicom import AE, evt

from histostudy.imaging import default_biplane
from histostudy.imaging.io._xa import XA_SOP_CLASS_UID, xa_dataset
from histostudy.lab import send_frames, stream_frames

T0 = dt.datetime(2024, 5, 6, 10, 30, 0)
INTERVAL_S = 0.2


@pytest.fixture(scope="module")
def objects():
    """Frames 0-4 of planes A and B (single-frame objects, 0.2 s apart), and a two-frame cine of A
    starting 1.0 s in (due when its second frame is taken, at 1.2 s)."""
    views = default_biplane(shape=(16, 20), pixel_mm=18.0)
    counts = np.random.default_rng(0).integers(100, 4000, size=(2,) + views[0].shape).astype(np.uint16)
    out = [xa_dataset(v, counts[0], acquisition_time=T0 + dt.timedelta(seconds=k * INTERVAL_S), uid_seed=f"p{k}")
           for k in range(5) for v in views]
    out.append(xa_dataset(views[0], counts, acquisition_time=T0 + dt.timedelta(seconds=1.0), frame_time_ms=200.0,
                          uid_seed="cine"))
    return out


@pytest.fixture
def scp():
    """A Storage SCP on a free port; ``arrivals``: perf_counter time of each C-STORE."""
    arrivals = []

    def on_store(event):
        arrivals.append(time.perf_counter())
        return 0x0000

    ae = AE(ae_title="HISTOSTUDY")
    ae.add_supported_context(XA_SOP_CLASS_UID, ["1.2.840.10008.1.2.1", "1.2.840.10008.1.2"])
    server = ae.start_server(("127.0.0.1", 0), block=False, evt_handlers=[(evt.EVT_C_STORE, on_store)])
    yield server.server_address[1], arrivals
    server.shutdown()


@pytest.mark.parametrize("pace", [1.0, 2.0])
def test_objects_go_out_at_their_acquisition_times_over_the_pace(objects, scp, pace):
    port, arrivals = scp
    sent = stream_frames(objects, "127.0.0.1", port, pace=pace)
    assert [o.index for o in sent] == list(range(len(objects))) and all(o.status == 0 for o in sent)
    due = np.array([o.due_s for o in sent])
    expected = np.r_[np.repeat(np.arange(5) * INTERVAL_S, 2), 1.2] / pace
    np.testing.assert_allclose(due, expected, atol=1e-6)
    # never early, and about on time on loopback (the SCP answers at once; slack for a busy machine)
    assert all(o.sent_s >= o.due_s - 1e-6 and o.late_s < 0.25 for o in sent)
    assert all(o.answered_s >= o.sent_s for o in sent)
    plane_a = np.array(arrivals)[::2][:5]  # plane A's frames 0-4 arrive 4 intervals apart in all
    assert plane_a[-1] - plane_a[0] == pytest.approx(4 * INTERVAL_S / pace, abs=0.15)


def test_send_frames_goes_at_once_and_pacing_needs_times(objects, scp):
    port, arrivals = scp
    t0 = time.perf_counter()
    assert send_frames(objects, "127.0.0.1", port) == [0] * len(objects)
    assert time.perf_counter() - t0 < 0.8 * 1.2  # not paced: faster than the 1.2 s the run took
    timeless = copy.deepcopy(objects[0])
    for keyword in ("AcquisitionDateTime", "ContentDate", "ContentTime"):
        delattr(timeless, keyword)
    with pytest.raises(ValueError, match=r"paths\[1\] .* cannot be paced: the object has no acquisition time"):
        stream_frames([objects[0], timeless], "127.0.0.1", port)
    with pytest.raises(ValueError, match="pace must be a finite speed-up > 0"):
        stream_frames(objects, "127.0.0.1", port, pace=0)
