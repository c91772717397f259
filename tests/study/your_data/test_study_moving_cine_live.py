"""histostudy.study.your_data.moving_cine_live: the moving cine streamed at its frame rate through the pose
receiver on loopback. The counts add up (sent = posed + dropped + refused), a tracker slowed down
on purpose drops pairs that are counted and never lets more than ``max_queued_pairs`` wait, the
track's losses and re-acquisitions match the records, and the accepted poses lie within 3 mm of the
truth. The tables and the figure are checked first on a run made up from the truth.

The streamed cine is full size (the shipped learned stages need frames of the size they were
trained on) and short (8 frames, about a second at 7.5 frames/s)."""

import time

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane
from histostudy.lab import SentObject
from histostudy.study.your_data.moving_cine import write_moving_cine
from histostudy.study.your_data.moving_cine_live import (
    MovingCineRun,
    count_table,
    frame_table,
    plot_focal_error,
    stream_moving_cine,
)
from histostudy.transducer import TransducerModel

FPS = 7.5


def counts_of(table):
    return table.set_index("quantity")["value"]


# --- the tables and the figure, on a made-up run --------------------------------------------------


@pytest.fixture(scope="module")
def small_cine(tmp_path_factory):
    return write_moving_cine(tmp_path_factory.mktemp("small"), seed=2, duration_s=0.8, fps=FPS,
                             views=default_biplane(shape=(96, 124), pixel_mm=3.08), render_spacing_mm=0.5)


def made_up_run(cine):
    """Frames 0, 2 and 5 posed (0 from scratch, 2 warm 0.5 mm off, 5 re-acquired and refused by the
    verdict, 1.5 mm off), frame 4's plane-B object refused, frames 1 and 3 skipped."""
    truth = cine.read_truth()
    records = []
    for pair, (k, kind, ok, off) in enumerate([(0, "from_scratch", True, 0.0), (2, "warm", True, 0.5),
                                               (5, "reacquired", False, 1.5)]):
        T = truth["T_carm_transducer"][k].copy()
        T[:3, 3] += [0.0, off, 0.0]
        when = (cine.acquired + pd.Timedelta(seconds=k / FPS)).isoformat()
        records.append({"pair_index": pair, "frame_times": [when, when], "tracking": kind, "accepted": ok,
                        "T_carm_transducer": T.tolist(), "seconds": {"latency": 0.1 * (k + 1), "queue": 0.0,
                                                                     "pose": 0.1}})
    sent = [SentObject(i, 0xC000 if i == 9 else 0, i // 2 / FPS, i // 2 / FPS, i // 2 / FPS + 0.01)
            for i in range(2 * cine.n_frames)]
    stats = {"pairs_processed": 3, "pairs_skipped": 2, "frames_unpaired": 1, "pairs_accepted": 2,
             "pairs_waiting_max": 1, "tracker": {"n_warm": 1, "n_from_scratch": 2, "n_lost": 1, "n_reacquired": 0}}
    return MovingCineRun(records=records, stats=stats, sent=sent, stream_s=cine.n_frames / FPS, wall_s=1.0,
                         max_queued_pairs=1)


def test_frame_table_and_counts_of_a_made_up_run(small_cine):
    run = made_up_run(small_cine)
    frames = frame_table(run, small_cine)
    assert small_cine.n_frames == 6 and frames["frame"].tolist() == list(range(6))
    assert frames["status"].tolist() == ["posed", "dropped", "posed", "dropped", "refused", "posed"]
    np.testing.assert_allclose(frames["focal_error_mm"].to_numpy(), [0.0, np.nan, 0.5, np.nan, np.nan, 1.5],
                               atol=1e-9)
    assert frames.loc[frames["status"] == "posed", "tracking"].tolist() == ["from_scratch", "warm", "reacquired"]
    assert frames["pair_index"].tolist() == [0, -1, 1, -1, -1, 2]
    counts = counts_of(count_table(run, frames))
    assert counts["pairs sent"] == 6 and counts["pairs refused (an object refused)"] == 1
    assert counts["sent = posed + dropped + refused"] and counts["frames left unpaired"] == 1
    assert counts["focal error largest (mm, accepted)"] == pytest.approx(0.5)  # the refused pose left out
    assert counts["focal error mean (mm, accepted)"] == pytest.approx(0.25)
    assert counts["latency largest (s)"] == pytest.approx(0.6) and counts["fraction of pairs posed"] == 0.5
    assert counts["track lost"] == 1 and counts["track re-acquired"] == 0
    fig = plot_focal_error(frames)
    labels = {t.get_text() for t in fig.axes[0].get_legend().get_texts()}
    assert labels == {"posed (accepted)", "refused by the verdict", "from scratch / re-acquired",
                      "dropped or refused (3)"}
    with pytest.raises(ValueError, match="frames must be frame_table's table with columns"):
        plot_focal_error(frames.drop(columns="speed_mm_s"))


# --- streamed through the receiver ------------------------------------------------------------------


@pytest.fixture(scope="module")
def cine(tmp_path_factory):
    return write_moving_cine(tmp_path_factory.mktemp("cine"), seed=7, duration_s=8 / FPS, fps=FPS)


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


def check_run(run, cine, max_queued_pairs):
    """What every run must satisfy, whatever the machine's speed; returns the frame table."""
    frames = frame_table(run, cine)
    stats, counts = run.stats, counts_of(count_table(run, frame_table(run, cine)))
    assert len(run.sent) == 2 * cine.n_frames and all(o.status == 0 for o in run.sent)
    assert stats["frames_unpaired"] == 0 and stats["pairs_waiting"] == 0
    assert stats["pairs_processed"] + stats["pairs_skipped"] == cine.n_frames == stats["pairs_completed"]
    assert counts["sent = posed + dropped + refused"]
    assert (frames["status"] == "posed").sum() == len(run.records) == stats["pairs_processed"]
    assert stats["pairs_waiting_max"] <= max_queued_pairs
    # the pairs come out in order, the gaps are the skipped ones, and the last frame is posed
    indices = [r["pair_index"] for r in run.records]
    assert indices == sorted(indices) and cine.n_frames - len(indices) == stats["pairs_skipped"]
    assert frames["status"].iloc[-1] == "posed"
    # losses and re-acquisitions: every lost warm start is re-estimated on its own frames
    kinds = frames.loc[frames["status"] == "posed", "tracking"].tolist()
    assert kinds[0] == "from_scratch"
    tracker = stats["tracker"]
    assert kinds.count("reacquired") == tracker["n_lost"] and kinds.count("warm") == tracker["n_warm"]
    assert tracker["n_reacquired"] == int(frames.loc[frames["tracking"] == "reacquired", "accepted"].sum())
    # accepted poses within 3 mm of the truth; the sender never early, and about on the C-arm's pace
    # (the receiver decodes on the same cores: a busy machine makes it answer late)
    accepted = frames.loc[frames["accepted"], "focal_error_mm"]
    assert len(accepted) >= 1 and accepted.max() < 3.0, frames
    assert all(o.sent_s >= o.due_s - 1e-6 for o in run.sent) and max(o.late_s for o in run.sent) < 2.0
    return frames


@pytest.mark.slow
@pytest.mark.parametrize("sender_process", [False, True], ids=["sender_thread", "sender_process"])
def test_a_paced_stream_through_the_fast_receiver_adds_up_and_tracks_within_3_mm(cine, model, tmp_path,
                                                                                  sender_process):
    run = stream_moving_cine(cine, model, 0, output_path=tmp_path / "poses.jsonl", max_queued_pairs=2,
                             sender_process=sender_process)
    assert (cine.n_frames - 1) / FPS - 1e-6 <= run.stream_s <= (cine.n_frames - 1) / FPS + 2.0
    check_run(run, cine, 2)


@pytest.mark.slow
def test_a_slow_tracker_drops_pairs_counted_and_never_falls_behind_more_than_the_queue(cine, model, tmp_path):
    """on_pose sleeps 0.5 s on the worker thread: the tracker cannot keep 7.5 pairs/s, the oldest
    waiting pairs are dropped, and a pair never waits longer than the one pair ahead of it."""
    sleep_s = 0.5

    def slow(record):
        time.sleep(sleep_s)

    run = stream_moving_cine(cine, model, 0, output_path=tmp_path / "poses.jsonl", max_queued_pairs=1,
                             on_pose=slow)
    frames = check_run(run, cine, 1)
    assert run.stats["pairs_skipped"] >= 1
    posed = frames[frames["status"] == "posed"]
    assert posed["queue_s"].max() <= posed["pose_s"].max() + sleep_s + 0.5
