"""``histostudy listen`` end to end (issue 21): the command in its own process receives the generated
lab-like dataset's biplane cine over DICOM on loopback (``--port 0``: the bound port read from its
first line), and every frame pair gets a pose within 0.1 mm of the same frames given as arrays to
a :class:`~histostudy.pose.Tracker` with the same seed, and within a few mm of the dataset's truth.
And its network options, in this process: loopback by default, a port in use refused at once
naming it (no output file), ``--allow``/``--modalities`` rejecting other senders at association,
and the TLS options checked.

The dataset's views are full size: the shipped learned stages (U-Net, VGG19) need detector images
of about the size they were trained on, and refuse (VGG19's pooling) views of a tenth of it.
"""

import json
import queue
import re
import shutil
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from histostudy.cli import build_parser, main
from histostudy.imaging import default_biplane, load_frame, load_views, save_views
from histostudy.lab import send_frames
from histostudy.pose import Tracker, TrackingConfig
from histostudy.study.your_data.lab_dataset import write_lab_dataset
from histostudy.transducer import TransducerModel

SEED = 3
N_FRAMES = 3


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
        listening = json.loads(first)  # stdout carries JSON only: first the bound port
        assert listening["event"] == "listening", first
        port = listening["port"]
        assert port > 0 and listening["host"] == "127.0.0.1" and listening["ae_title"] == "HISTOSTUDY"
        assert listening["output"] == str(output)
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
    rest = []
    while (line := stdout.get(timeout=10)) is not None:
        rest.append(line)
    summary = json.loads(rest[-1])  # and last the statistics, as JSON
    assert summary["event"] == "summary" and summary["pairs_processed"] == N_FRAMES
    assert len(re.findall(r" pair \d ", log.read_text())) == N_FRAMES  # a line per pose on stderr

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


@pytest.fixture
def small_views_file(tmp_path):
    path = tmp_path / "views.json"
    save_views(path, default_biplane(shape=(48, 62), pixel_mm=6.16))
    return path


def test_listen_binds_loopback_unless_told_otherwise():
    args = build_parser().parse_args(["listen", "--port", "0", "--views", "views.json"])
    assert args.host == "127.0.0.1" and args.allow == [] and args.modalities is None and args.tls_cert is None


def test_a_port_in_use_is_refused_at_once_naming_it_and_no_output_is_created(tmp_path, small_views_file, capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        code = main(["listen", "--port", str(port), "--views", str(small_views_file), "--output",
                     str(tmp_path / "poses.jsonl"), "--timeout-s", "5"])
    captured = capsys.readouterr()
    error = captured.err.split(": ", 1)[1].strip()
    assert code == 2 and json.loads(captured.out) == {"command": "listen", "exit_code": 2, "refused": False,
                                                      "bad_input": True, "error": error}
    assert re.search(rf"histostudy listen: \[Errno \d+\] cannot listen on 127.0.0.1:{port}: .*in use", captured.err)
    assert not (tmp_path / "poses.jsonl").exists()


def test_listen_rejects_a_sender_off_its_allow_list_at_association(tmp_path, small_views_file, capsys):
    """``--allow`` and ``--modalities`` together: their AE titles may associate (a C-ECHO), another
    is rejected (A-ASSOCIATE-RJ reason 3), counted in the final statistics; nothing is written."""
    from pynetdicom import AE
    from pynetdicom.sop_class import Verification

    modalities = tmp_path / "modalities.json"
    modalities.write_text(json.dumps({"modalities": {"carm_b": {"ae_title": "CARM_B", "host": "127.0.0.1"}}}))
    results = []

    def echo(port: int, calling: str) -> None:
        ae = AE(ae_title=calling)
        ae.add_requested_context(Verification)
        assoc = ae.associate("127.0.0.1", port, ae_title="HISTOSTUDY")
        results.append((calling, assoc.is_established, assoc.acceptor.primitive.diagnostic if assoc.is_rejected
                        else None))
        if assoc.is_established:
            assoc.release()

    port = free_port()
    command = threading.Thread(target=lambda: results.append(main([
        "listen", "--port", str(port), "--views", str(small_views_file), "--output", str(tmp_path / "poses.jsonl"),
        # the listener stops on its own after --timeout-s: long enough for the three associations on a
        # loaded machine (at 4 s, a CI worker beside the smoke study reached the third after it had stopped)
        "--allow", "CARM_A", "--modalities", str(modalities), "--timeout-s", "20", "-q"])))
    command.start()
    wait_for_listening(port)
    for calling in ("CARM_A", "CARM_B", "ROGUE"):
        echo(port, calling)
    command.join(60)
    assert results == [("CARM_A", True, None), ("CARM_B", True, None), ("ROGUE", False, 3), 0]
    captured = capsys.readouterr()
    out = [json.loads(line) for line in captured.out.splitlines()]  # stdout: JSON lines only
    assert out[0] == {"event": "listening", "host": "127.0.0.1", "port": port, "ae_title": "HISTOSTUDY",
                      "output": str(tmp_path / "poses.jsonl"), "tls": False}
    assert captured.err == ""  # -q: nothing but errors on stderr
    stats = out[-1]  # the statistics, printed last
    assert (stats["associations"], stats["associations_rejected"], stats["objects_received"]) == (2, 1, 0)
    assert (tmp_path / "poses.jsonl").read_text() == ""


@pytest.mark.parametrize("options, message", [
    (["--tls-ca", "ca.pem"], "--tls-key and --tls-ca need --tls-cert"),
    (["--tls-cert", "server.pem"], "tls cert 'server.pem': no such file"),
    (["--allow", "CARM_A@carm.local"], "host must be an IP address"),
    (["--modalities", "missing.json"], "modalities file 'missing.json': no such file"),
])
def test_bad_network_options_are_refused_naming_them(tmp_path, small_views_file, capsys, monkeypatch, options,
                                                     message):
    monkeypatch.chdir(tmp_path)
    code = main(["listen", "--port", "0", "--views", str(small_views_file), *options])
    assert code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "poses.jsonl").exists()


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_for_listening(port: int, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            assert time.monotonic() < deadline, "listen did not start"
            time.sleep(0.05)
