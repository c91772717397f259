"""The live receiver over a stretch of a procedure (issue 56; the 30-minute run is
benchmarks/bench_receiver_soak.py): a biplane cine paced at 15 frames per second per plane for two
minutes, with pairs stored twice, connections dropped mid-object and hostile peers mixed in. No
frame is refused or lost, none is posed twice, memory does not grow, and the threads end."""

import json
import logging
import threading

import pytest
from receiver_stub import StubTracker, receiver_with, run_soak, small_views

SOAK_S = 120.0


@pytest.mark.slow
@pytest.mark.longest
def test_two_minutes_of_cine_lose_nothing_pose_nothing_twice_and_hold_memory_and_threads(tmp_path, caplog):
    views = small_views()
    threads_before = set(threading.enumerate())
    with caplog.at_level(logging.CRITICAL):  # every hostile peer is logged
        receiver = receiver_with(views, tmp_path, StubTracker(keep_images=False), max_queued_pairs=1,
                                 network_timeout_s=5.0)
        with receiver:
            soak = run_soak(receiver, views, seconds=SOAK_S, hostile_per_min=30.0)
    sent, stats, samples = soak["sent"], soak["stats"], soak["samples"]
    lines = [json.loads(line) for line in (tmp_path / "poses.jsonl").read_text().splitlines()]
    posed = [uid for line in lines for uid in line["instance_uids"]]

    # every frame the C-arm sent is answered success, its copies included, and none is posed twice
    assert sent["frames"] > 1000 and set(sent["statuses"]) == {0}
    assert sum(sent["statuses"].values()) == sent["frames"] + sent["resent"]
    assert len(posed) == len(set(posed)) and set(posed) <= {uid for pair in sent["uids"] for uid in pair}
    assert stats["objects_duplicate"] == sent["resent"] > 0 and sent["dropped"] > 0
    # live: each completed pair posed or dropped for a newer one, none waiting at the end
    assert stats["pairs_completed"] == stats["pairs_processed"] + stats["pairs_skipped"]
    assert sum(soak["hostile"].values()) > 20
    # memory flat after the first half minute (the imports and caches settled), threads back
    settled = next(s["rss"] for s in samples if s["t_s"] >= 30.0)
    assert samples[-1]["rss"] <= 1.10 * settled, [round(s["rss"] / 2 ** 20, 1) for s in samples]
    assert [t.name for t in threading.enumerate() if t not in threads_before] == []
