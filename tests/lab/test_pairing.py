"""Tests of histostudy.lab.pairing: biplane frames paired by acquisition time, and the frames' times
read from DICOM XA objects (AcquisitionDateTime + frame index x FrameTime)."""

import datetime as dt
import warnings

import numpy as np
import pytest
from pydicom.dataset import Dataset

from histostudy.imaging import default_biplane
from histostudy.imaging.io._xa import xa_dataset
from histostudy.lab.pairing import BiplanePairer, PlaneFrame, frame_times, posix_seconds

T0 = dt.datetime(2024, 5, 6, 10, 30, 0)


def frame(plane, ms, interval_ms=66.7):
    return PlaneFrame(plane, posix_seconds(T0) + ms / 1000.0, None if interval_ms is None else interval_ms / 1000.0,
                      data=(plane, ms))


def run(pairer, frames):
    sets, dropped = [], []
    for f in frames:
        out = pairer.add(f)
        sets += [tuple(g.data for g in s) for s in out.sets]
        dropped += [g.data for g in out.dropped]
    return sets, dropped


def test_one_cine_per_plane_pairs_frame_by_frame_in_either_order():
    a = [frame("A", i * 66.7) for i in range(4)]
    b = [frame("B", i * 66.7 + 5.0) for i in range(4)]  # plane B pulsed 5 ms after A
    for order in (a + b, b + a, [f for pair in zip(a, b) for f in pair]):
        pairer = BiplanePairer(["A", "B"])
        sets, dropped = run(pairer, order)
        assert sets == [(("A", i * 66.7), ("B", i * 66.7 + 5.0)) for i in range(4)] and not dropped
        assert pairer.pending() == {"A": 0, "B": 0} and (pairer.n_added, pairer.n_sets) == (8, 4)


def test_frames_pair_within_half_a_frame_interval_only():
    pairer = BiplanePairer(["A", "B"])
    assert pairer.tolerance(frame("A", 0), frame("B", 0)) == pytest.approx(0.03335)
    assert not run(pairer, [frame("A", 0), frame("B", 33.4)])[0]  # just over half of 66.7 ms
    assert run(BiplanePairer(["A", "B"]), [frame("A", 0), frame("B", 33.3)])[0]
    # the shorter of two intervals; single frames take default_interval_s; tolerance_s overrides
    assert pairer.tolerance(frame("A", 0, 40.0), frame("B", 0)) == pytest.approx(0.020)
    assert BiplanePairer(["A", "B"], default_interval_s=0.1).tolerance(frame("A", 0, None)) == pytest.approx(0.05)
    assert BiplanePairer(["A", "B"], tolerance_s=0.002).tolerance(frame("A", 0)) == 0.002


def test_the_nearest_partner_is_taken_and_a_missed_frame_is_dropped():
    """Plane B misses its second pulse: A's second frame is dropped as unpaired once B has moved
    past it, and the other frames still pair with their own partners."""
    pairer = BiplanePairer(["A", "B"])
    sets, dropped = run(pairer, [frame("A", 0), frame("A", 66.7), frame("A", 133.4),
                                 frame("B", 1.0), frame("B", 134.0)])
    assert sets == [(("A", 0), ("B", 1.0)), (("A", 133.4), ("B", 134.0))]
    assert dropped == [("A", 66.7)] and pairer.n_dropped == 1 and pairer.pending() == {"A": 0, "B": 0}


def test_pending_frames_are_bounded_and_flushed():
    pairer = BiplanePairer(["A", "B"], max_pending=3)
    sets, dropped = run(pairer, [frame("A", ms) for ms in (0, 66.7, 133.4, 200.1, 266.8)])
    assert not sets and dropped == [("A", 0), ("A", 66.7)] and pairer.pending()["A"] == 3
    assert [f.data for f in pairer.flush()] == [("A", 133.4), ("A", 200.1), ("A", 266.8)]
    assert pairer.n_dropped == 5 and pairer.pending() == {"A": 0, "B": 0}


def test_one_plane_makes_sets_of_one_and_three_planes_wait_for_all():
    assert run(BiplanePairer(["A"]), [frame("A", 0)])[0] == [(("A", 0),)]
    sets, _ = run(BiplanePairer(["A", "B", "C"]), [frame("A", 0), frame("C", 2), frame("B", 1)])
    assert sets == [(("A", 0), ("B", 1), ("C", 2))]


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="planes must be unique"):
        BiplanePairer(["A", "A"])
    with pytest.raises(TypeError, match="planes must be a sequence"):
        BiplanePairer("AB")
    with pytest.raises(ValueError, match="tolerance_s must be None or a finite time > 0"):
        BiplanePairer(["A", "B"], tolerance_s=0)
    with pytest.raises(ValueError, match="max_pending must be an integer >= 1"):
        BiplanePairer(["A", "B"], max_pending=0)
    with pytest.raises(ValueError, match=r"frame.plane must be one of \('A', 'B'\), got 'C'"):
        BiplanePairer(["A", "B"]).add(frame("C", 0))
    with pytest.raises(ValueError, match="time_s must be a finite time"):
        PlaneFrame("A", float("nan"))
    with pytest.raises(ValueError, match="interval_s must be None or a finite interval > 0"):
        PlaneFrame("A", 0.0, 0.0)


def test_frame_times_of_an_xa_cine_and_a_single_frame():
    view = default_biplane()[0]
    counts = np.zeros((3,) + view.shape, np.uint16)
    cine = xa_dataset(view, counts, acquisition_time=T0, frame_time_ms=40.0)
    times, interval = frame_times(cine)
    assert times == [T0, T0 + dt.timedelta(milliseconds=40), T0 + dt.timedelta(milliseconds=80)]
    assert interval == pytest.approx(0.040)
    single = xa_dataset(view, counts[0], acquisition_time=T0)
    assert frame_times(single) == ([T0], None)


def test_frame_times_from_other_tags():
    ds = Dataset()
    ds.AcquisitionDateTime = "20240506103000.250000+0200"  # with its UTC offset
    ds.NumberOfFrames, ds.FrameIncrementPointer = 3, 0x00181065
    ds.FrameTimeVector = [0, 50, 70]  # ms between frames
    times, interval = frame_times(ds)
    assert [posix_seconds(t) - posix_seconds(times[0]) for t in times] == pytest.approx([0, 0.05, 0.12])
    assert times[0].utcoffset() == dt.timedelta(hours=2) and interval == pytest.approx(0.05)  # the shortest step
    assert posix_seconds(times[0]) == pytest.approx(posix_seconds(dt.datetime(2024, 5, 6, 8, 30, 0, 250000)))
    # no AcquisitionDateTime: the acquisition date and time, then the content date and time
    ds = Dataset()
    ds.ContentDate, ds.ContentTime = "20240506", "103000.5"
    assert frame_times(ds) == ([dt.datetime(2024, 5, 6, 10, 30, 0, 500000)], None)
    ds.AcquisitionDate, ds.AcquisitionTime = "20240506", "103001"
    assert frame_times(ds)[0] == [dt.datetime(2024, 5, 6, 10, 30, 1)]
    # an enhanced object: each frame's own FrameAcquisitionDateTime
    ds = Dataset()
    ds.NumberOfFrames = 2
    ds.PerFrameFunctionalGroupsSequence = []
    for stamp in ("20240506103000", "20240506103000.1"):
        content, item = Dataset(), Dataset()
        content.FrameAcquisitionDateTime = stamp
        item.FrameContentSequence = [content]
        ds.PerFrameFunctionalGroupsSequence.append(item)
    assert frame_times(ds) == ([T0, T0 + dt.timedelta(milliseconds=100)], pytest.approx(0.1))


def test_frame_times_refuse_objects_without_a_usable_time():
    with pytest.raises(ValueError, match=r"lacks AcquisitionDateTime \(0008,002A\)"):
        frame_times(Dataset())
    ds = Dataset()
    ds.AcquisitionDateTime, ds.NumberOfFrames = "20240506103000", 2
    with pytest.raises(ValueError, match=r"needs FrameTime \(0018,1063\)"):
        frame_times(ds)
    ds.FrameTime = -5
    with pytest.raises(ValueError, match="FrameTime .* must be a finite interval > 0 ms"):
        frame_times(ds)
    ds.FrameTime = 66.7
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pydicom warns of the invalid DT value as it is set
        ds.AcquisitionDateTime = "yesterday"
    with pytest.raises(ValueError, match="AcquisitionDateTime .* must be a DICOM date-time"):
        frame_times(ds)
