"""histostudy.study.your_data (its live part, _live): notebook 06's live section — the received poses beside the tracked
ones, the receiver's throughput, the live figure — on synthetic records (the stream itself runs in
notebook 06 and in tests/cli/test_cli_listen.py)."""

import math

import numpy as np
import pandas as pd
import pytest

from histostudy.study.your_data._live import LiveFocalFigure, compare_with_tracked, throughput_table


def record(pair, focal, *, frame=None, accepted=True, tracking="warm"):
    """A receiver's line (the fields these functions read); ``focal`` None: a pair whose pose failed."""
    frame = pair if frame is None else frame
    out = {"pair_index": pair, "frame_indices": [frame, frame], "planes": ["A", "B"], "accepted": accepted,
           "tracking": tracking, "seconds": {"latency": 0.5 + pair}}
    if focal is None:
        out["error"] = "PoseEstimationError: no transducer feature"
    else:
        out["focal_point_mm"] = list(focal)
    return out


@pytest.fixture
def tracked():
    """track_cine's table for frames 0-2."""
    focal = np.array([[1.0, 2.0, 3.0], [1.5, 2.0, 3.0], [2.0, 2.5, 3.0]])
    return pd.DataFrame({"frame": [0, 1, 2], **{f"focal_{a}_mm": focal[:, i] for i, a in enumerate("xyz")},
                         "accepted": [True, True, False], "seconds": 1.0})


def test_received_poses_are_set_beside_the_tracked_ones_of_the_same_frames(tracked):
    records = [record(0, [1.0, 2.0, 3.0], tracking="from_scratch"), record(1, [1.5, 2.3, 3.4]),
               record(2, [5.0, 6.0, 7.0], frame=2, accepted=False), record(3, None, frame=3, accepted=False)]
    table = compare_with_tracked(records, tracked)
    assert table["pair"].tolist() == [0, 1, 2, 3] and table["frame"].tolist() == [0, 1, 2, 3]
    assert table["tracking"].tolist() == ["from_scratch", "warm", "warm", "warm"]
    np.testing.assert_allclose(table["focal_difference_mm"][:3], [0.0, 0.5, np.linalg.norm([3.0, 3.5, 4.0])])
    assert table["accepted"].tolist() == [True, True, False, False]
    assert table["tracked_accepted"][:3].tolist() == [True, True, False]
    # a pair without a pose, of a frame not tracked: no focal point, no difference
    assert math.isnan(table["focal_difference_mm"][3]) and table[["focal_x_mm", "focal_y_mm"]].iloc[3].isna().all()
    assert table["latency_s"].tolist() == [0.5, 1.5, 2.5, 3.5]
    # pairs matched by frame, not by their order of arrival
    swapped = compare_with_tracked([record(0, [2.0, 2.5, 3.0], frame=2)], tracked)
    assert swapped["focal_difference_mm"].tolist() == [0.0]
    with pytest.raises(ValueError, match=r"tracked must be track_cine's table with columns .*focal_x_mm"):
        compare_with_tracked(records, tracked.drop(columns="focal_x_mm"))


def test_throughput_table_gives_frames_per_second_and_seconds_per_stage():
    stats = {"frames_received": 8, "pairs_processed": 4, "pairs_accepted": 3, "frames_per_s": 1.25,
             "pose_frames_per_s": 2.0, "seconds_per_pair": {"decode": 0.01, "segmentation": 0.4, "total": 1.0,
                                                            "pose": 1.1, "latency": 1.3}}
    table = throughput_table(stats).set_index("quantity")["value"]
    assert table["frames/s (first frame to last pose)"] == 1.25 and table["frames/s (pose work alone)"] == 2.0
    assert table["pairs posed"] == 4 and table["frames received"] == 8 and table["pairs accepted"] == 3
    assert table["seconds per pair: segmentation"] == 0.4 and table["seconds per pair: latency"] == 1.3
    assert len(table) == 5 + 5


def test_the_live_figure_draws_each_record_as_it_arrives(tracked):
    live = LiveFocalFigure(3, reference=tracked, show=False)
    lines = {line.get_label(): line for line in live.ax.lines}
    x, y, z, refused = (lines[name] for name in ("focal x", "focal y", "focal z", "refused"))
    live(record(0, [1.0, 2.0, 3.0]))
    assert list(x.get_xdata()) == [0] and list(z.get_ydata()) == [3.0]
    live(record(1, None, accepted=False))  # no pose: kept, not drawn
    live(record(2, [2.0, 2.5, 3.5], accepted=False))
    assert list(y.get_xdata()) == [0, 2] and list(y.get_ydata()) == [2.0, 2.5]
    assert list(refused.get_xdata()) == [2, 2, 2] and list(refused.get_ydata()) == [2.0, 2.5, 3.5]
    assert len(live.records) == 3
    # the y range follows the points; the x range stays the pairs'
    lo, hi = live.ax.get_ylim()
    assert lo <= 1.0 and hi >= 3.5 and live.ax.get_xlim() == (-0.5, 2.5)
    assert {t.get_text() for t in live.ax.get_legend().get_texts()} == {
        "tracked from arrays", "focal x", "focal y", "focal z", "refused"}
    with pytest.raises(ValueError, match="n_pairs must be an integer >= 1, got 0"):
        LiveFocalFigure(0, show=False)
