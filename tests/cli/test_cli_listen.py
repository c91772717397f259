"""``histostudy listen`` end to end (issue 21): the command in its own process receives the generated
lab-like dataset's biplane cine over DICOM on loopback (``--port 0``: the bound port read from its
first line), and every frame pair gets a pose within 0.1 mm of the same frames given as arrays to
a :class:`~histostudy.pose.Tracker` with the same seed, and within a few mm of the dataset's truth.

The dataset's views are full size: the shipped learned stages (U-Net, VGG19) need detector images
of about the size they were trained on, and refuse (VGG19's pooling) views of a tenth of it.
"""

import json
import queue
import re
import shutil
import subprocess
import sys
import threading

import numpy as np
import pytest

from histostudy.imaging import load_frame, load_views
from histostudy.lab import send_frames
from histostudy.pose import Tracker, TrackingConfig
from histostudy.study.lab_dataset import write_lab_dataset
from histostudy.transducer import TransducerModel

SEED = 3
N_FRAMES = 3
#: The first line ``histostudy listen`` prints once it listens.
LISTENING = re.compile(r"^listening on (?P<host>\S+):(?P<port>\d+) as (?P<ae>\S+); poses to (?P<output>.+)$")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    return write_lab_dataset(tmp_path_factory.mktemp("lab"), seed=5, n_cine_frames=N_FRAMES)


def lines_of(stream, lines: queue.Queue) -> None:
    for line in stream:
        lines.put(line.rstrip("\n"))
    lines.put(None)


@pytest.mark.slow
@pytest.mark.parametrize("fast", [False, True], ids=["full_frame", "fast"])
def test_listen_prints_its_port_and_poses_every_pair_of_a_cine_sent_to_it(lab, tmp_path, fast):
    output = tmp_path / "poses.jsonl"
    command = [sys.executable, "-m", "histostudy.cli", "listen", "--port", "0", "--host", "127.0.0.1",
               "--views", str(lab.views), "--output", str(output), "--max-pairs", str(N_FRAMES),
               "--seed", str(SEED), "--timeout-s", "400", "--fast" if fast else "--no-fast",
               "--max-queued-pairs", "all"]  # a cine sent at once: every pair posed
    log = tmp_path / "listen.err"
    with open(log, "w") as err:  # a file, not a pipe: a full pipe would block the command
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=err, text=True, cwd=tmp_path)
    stdout: queue.Queue = queue.Queue()
    threading.Thread(target=lines_of, args=(process.stdout, stdout), daemon=True).start()
    try:
        first = stdout.get(timeout=120)  # the models load before the receiver listens
        assert first is not None, f"listen exited ({process.wait(10)}) before listening: {log.read_text()}"
        match = LISTENING.match(first)
        assert match, f"first line {first!r} does not name the bound port"
        port = int(match["port"])
        assert port > 0 and match["host"] == "127.0.0.1" and match["ae"] == "HISTOSTUDY"
        assert match["output"] == str(output)
        paths = [str(p) for p in lab.cine]
        if shutil.which("storescu"):
            sent = subprocess.run(["storescu", "-aec", "HISTOSTUDY", "127.0.0.1", str(port), *paths],
                                  capture_output=True, text=True, timeout=120)
            assert sent.returncode == 0, sent.stderr
        else:
            assert send_frames(paths, "127.0.0.1", port) == [0, 0]
        code = process.wait(timeout=400)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert code == 0, log.read_text()

    records = [json.loads(line) for line in output.read_text().splitlines()]
    assert [r["pair_index"] for r in records] == list(range(N_FRAMES))
    assert [r["frame_indices"] for r in records] == [[k, k] for k in range(N_FRAMES)]
    assert all(r["planes"] == ["A", "B"] and "error" not in r for r in records)

    # The same frames as arrays, through a Tracker set as the receiver sets its own (same seed, the
    # command's model, Levenberg-Marquardt, no retries, no full-frame steps from scratch when fast).
    views = load_views(lab.views)
    live = TrackingConfig(scratch_full_frames=False) if fast else False
    tracker = Tracker(TransducerModel.build(spacing_mm=0.47), views, rng=SEED, fast=live, mode="fast",
                      retry_hypotheses=False)
    truth = json.loads(lab.truth.read_text())["cine_T_carm_transducer"]
    for k, record in enumerate(records):
        frames = [load_frame(path, view, line_integrals=False, frame_index=k) for path, view in zip(lab.cine, views)]
        direct = tracker.update([f.image for f in frames])
        assert record["accepted"] == bool(direct.verdict.ok) and record["tracking"] == tracker.last_kind
        focal = np.asarray(record["focal_point_mm"])
        assert np.linalg.norm(focal - direct.focal_point_mm) < 0.1, f"pair {k}"
        assert np.linalg.norm(focal - np.asarray(truth[k])[:3, 3]) < 3.0, f"pair {k} far from the truth"
    assert all(r["accepted"] for r in records)
