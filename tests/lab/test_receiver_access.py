"""Tests of who may send frames to the live receiver, and where it listens (histostudy.lab.access):
the allow-list of calling AE titles and addresses, the called AE title, the A-ASSOCIATE-RJ a
refused sender gets at negotiation (before any object is read), and a clear error, with no file
created, for an address already in use.

The pose work is receiver_stub.py's stub tracker; the frames are small XA objects sent over loopback
with :func:`histostudy.lab.send_frames` (or a C-ECHO through pynetdicom where a bound address is needed).
"""

import errno
import json
import logging
import socket
import threading

import pytest
from receiver_stub import (
    StubTracker,
    associate_rq,
    connect,
    pair_objects,
    reaction,
    read_lines,
    receiver_with,
    small_views,
    wait_for_count,
)

from histostudy.lab import (
    AllowList,
    FrameReceiver,
    Modality,
    ReceiverConfig,
    listen,
    load_modalities,
    parse_allow,
    send_frames,
)

#: What send_frames says of an association rejected with reason 3 or 7 (result 1, source 1).
CALLING_NOT_RECOGNISED = r"rejected the association \(A-ASSOCIATE-RJ result 1, source 1, reason 3: calling AE"
CALLED_NOT_RECOGNISED = r"rejected the association \(A-ASSOCIATE-RJ result 1, source 1, reason 7: called AE"


@pytest.fixture(scope="module")
def views():
    return small_views()


def nothing_received(receiver, output) -> bool:
    """No object read, no frame stored, no pair posed, no line written."""
    stats = receiver.stats()
    return (stats["objects_received"], stats["frames_received"], stats["pairs_processed"], stats["associations"]) \
        == (0, 0, 0, 0) and read_lines(output) == []


def echo_from(address: str, port: int, calling: str, called: str = "HISTOSTUDY") -> tuple[bool, int | None]:
    """A C-ECHO association from ``address`` (bound locally): (established, the rejection's reason)."""
    from pynetdicom import AE
    from pynetdicom.sop_class import Verification

    ae = AE(ae_title=calling)
    ae.add_requested_context(Verification)
    assoc = ae.associate("127.0.0.1", port, ae_title=called, bind_address=(address, 0))
    established = assoc.is_established
    reason = assoc.acceptor.primitive.diagnostic if assoc.is_rejected else None
    if established:
        assert int(assoc.send_c_echo().Status) == 0
        assoc.release()
    return established, reason


def test_an_ae_not_on_the_list_is_rejected_at_negotiation_and_nothing_of_it_is_stored(views, tmp_path, caplog):
    """A calling AE title off the list gets A-ASSOCIATE-RJ (1, 1, 3) before any object: 0 objects
    read, 0 frames stored or posed; logged with its address and AE titles and counted. The listed
    AE's frames are then received and posed."""
    tracker = StubTracker()
    with caplog.at_level(logging.WARNING, logger="histostudy.lab.receiver"), \
            receiver_with(views, tmp_path, tracker, allow=["CARM_A", "CARM_B"], max_queued_pairs=None) as receiver:
        with pytest.raises(ConnectionError, match=CALLING_NOT_RECOGNISED):
            send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, calling_ae_title="ROGUE")
        assert nothing_received(receiver, tmp_path / "poses.jsonl") and tracker.images == []
        wait_for_count(receiver, "associations_rejected", 1)
        assert send_frames(pair_objects(views, 1), "127.0.0.1", receiver.port, calling_ae_title="CARM_B") == [0, 0]
        assert receiver.wait_for_pairs(1, timeout_s=30)
    stats = receiver.stats()
    assert (stats["associations_rejected"], stats["associations"], stats["objects_received"],
            stats["frames_received"], stats["pairs_processed"]) == (1, 1, 2, 2, 1)
    (rejection,) = stats["last_association_rejections"]
    assert rejection["calling_ae_title"] == "ROGUE" and rejection["called_ae_title"] == "HISTOSTUDY"
    assert rejection["reason"] == 3 and rejection["peer"].startswith("127.0.0.1:")
    assert "'ROGUE' is none of ['CARM_A', 'CARM_B']" in rejection["why"]
    (logged,) = [r.getMessage() for r in caplog.records if "rejected an association" in r.getMessage()]
    assert f"from {rejection['peer']} (calling AE title 'ROGUE', called 'HISTOSTUDY')" in logged
    assert "result 1, source 1, reason 3" in logged
    assert [line["pair_index"] for line in read_lines(tmp_path / "poses.jsonl")] == [0]


@pytest.mark.parametrize("allow", [None, ["CARM_A"]], ids=["no_list", "list"])
def test_a_wrong_called_ae_title_is_rejected_with_reason_7(views, tmp_path, allow):
    """The called AE title must be the receiver's own, with or without an allow-list."""
    with receiver_with(views, tmp_path, StubTracker(), allow=allow) as receiver:
        with pytest.raises(ConnectionError, match=CALLED_NOT_RECOGNISED):
            send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, ae_title="OTHER_SCP",
                        calling_ae_title="CARM_A")
        assert nothing_received(receiver, tmp_path / "poses.jsonl")
        stats = wait_for_count(receiver, "associations_rejected", 1)  # counted after the A-ASSOCIATE-RJ went
    (rejection,) = stats["last_association_rejections"]
    assert stats["associations_rejected"] == 1 and rejection["reason"] == 7
    assert rejection["called_ae_title"] == "OTHER_SCP"
    assert "not this receiver's AE title 'HISTOSTUDY'" in rejection["why"]


def test_a_listed_ae_calling_from_another_address_is_rejected(views, tmp_path):
    """CARM_A may call only from 127.0.0.2: from 127.0.0.1 it is rejected (reason 3), from 127.0.0.2
    accepted; CARM_B, listed without a host, from either."""
    try:
        with socket.socket() as probe:
            probe.bind(("127.0.0.2", 0))
    except OSError:
        pytest.skip("this machine cannot bind 127.0.0.2 (Linux routes all of 127/8 to loopback)")
    with receiver_with(views, tmp_path, StubTracker(), allow=["CARM_A@127.0.0.2", "CARM_B"]) as receiver:
        with pytest.raises(ConnectionError, match=CALLING_NOT_RECOGNISED):
            send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, calling_ae_title="CARM_A")
        assert nothing_received(receiver, tmp_path / "poses.jsonl")
        assert echo_from("127.0.0.1", receiver.port, "CARM_A") == (False, 3)
        assert echo_from("127.0.0.2", receiver.port, "CARM_A") == (True, None)
        assert echo_from("127.0.0.1", receiver.port, "CARM_B") == (True, None)
        assert echo_from("127.0.0.2", receiver.port, "CARM_B") == (True, None)
        stats = wait_for_count(receiver, "associations_rejected", 2)
    assert (stats["associations_rejected"], stats["associations"], stats["objects_received"]) == (2, 3, 0)
    assert all("'CARM_A' may call only from ['127.0.0.2'], not from 127.0.0.1" in r["why"]
               for r in stats["last_association_rejections"])


def test_without_a_list_any_calling_ae_may_send_and_the_log_warns(views, tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="histostudy.lab.receiver"), \
            receiver_with(views, tmp_path, StubTracker()) as receiver:
        assert send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, calling_ae_title="ANYONE") == [0, 0]
        assert receiver.wait_for_pairs(1, timeout_s=30)
    assert receiver.stats()["associations_rejected"] == 0
    assert any("no allow-list of modalities: any calling AE title" in r.getMessage() for r in caplog.records)


def test_a_connection_that_sends_nothing_is_closed_before_it_holds_an_association(views, tmp_path):
    """Connections silent for ``first_bytes_wait_s`` are closed, counted (``connections_silent``) and
    never make an association; one whose request comes within it is accepted, and the C-arm is
    served meanwhile (issue 56: idle peers must not crowd it out)."""
    import time

    receiver = receiver_with(views, tmp_path, StubTracker(), allow=["CARM@127.0.0.1"])
    receiver.first_bytes_wait_s = 0.5
    with receiver:
        silent = [connect(receiver.port) for _ in range(20)]
        late = connect(receiver.port)
        t0 = time.monotonic()
        time.sleep(0.2)
        late.sendall(associate_rq(calling="CARM"))
        assert reaction(late) == "accepted"
        assert echo_from("127.0.0.1", receiver.port, "CARM") == (True, None)
        assert [reaction(sock) for sock in silent] == ["closed"] * 20
        waited = time.monotonic() - t0
        for sock in [*silent, late]:
            sock.close()
        wait_for_count(receiver, "connections_silent", 20)
    stats = receiver.stats()
    assert 0.5 <= waited < 5.0
    assert (stats["connections"], stats["connections_silent"], stats["associations"],
            stats["associations_rejected"]) == (22, 20, 2, 0)


@pytest.mark.parametrize("split", [False, True], ids=["whole", "in_two_parts"])
def test_a_stranger_is_rejected_whether_its_request_comes_whole_or_in_parts(views, tmp_path, split):
    """An A-ASSOCIATE-RQ off the list is rejected with reason 3 and counted once, whether it is
    judged on the connection's first bytes (whole) or, its fixed part not yet there, at
    negotiation (in two parts, 0.3 s apart): the same answer and record either way."""
    import time

    with receiver_with(views, tmp_path, StubTracker(), allow=["CARM"]) as receiver:
        request = associate_rq(calling="STRANGER")
        with connect(receiver.port) as sock:
            if split:
                sock.sendall(request[:20])
                time.sleep(0.3)
                sock.sendall(request[20:])
            else:
                sock.sendall(request)
            assert reaction(sock) == "rejected"
        wait_for_count(receiver, "associations_rejected", 1)
        stats = receiver.stats()
    (rejection,) = stats["last_association_rejections"]
    assert (rejection["calling_ae_title"], rejection["reason"]) == ("STRANGER", 3)
    assert "'STRANGER' is none of ['CARM']" in rejection["why"]
    assert (stats["associations"], stats["objects_received"]) == (0, 0)


def test_the_modalities_file_and_the_allow_texts_make_the_same_list(tmp_path):
    path = tmp_path / "modalities.json"
    path.write_text(json.dumps({"modalities": {"carm_a": {"ae_title": "CARM_A", "host": "192.168.10.21"},
                                               "pacs": {"ae_title": "PACS", "port": 104},
                                               "v6": {"ae_title": "CARM_C", "host": "::ffff:10.0.0.7"}}}))
    listed = load_modalities(path)
    assert [(m.name, m.ae_title, m.host) for m in listed.modalities] == [
        ("carm_a", "CARM_A", "192.168.10.21"), ("pacs", "PACS", None), ("v6", "CARM_C", "10.0.0.7")]
    assert [str(m) for m in listed.modalities] == ["CARM_A@192.168.10.21", "PACS", "CARM_C@10.0.0.7"]
    assert listed.ae_titles == ["CARM_A", "CARM_C", "PACS"]
    texts = AllowList.of(["CARM_A@192.168.10.21", "PACS", parse_allow("CARM_C@10.0.0.7")])
    assert [(m.ae_title, m.host) for m in texts.modalities] == [(m.ae_title, m.host) for m in listed.modalities]
    assert listed.allows("CARM_A", "192.168.10.21") and not listed.allows("CARM_A", "192.168.10.22")
    assert listed.allows("PACS", "10.1.2.3") and listed.allows("CARM_C", "::ffff:10.0.0.7")
    assert not listed.allows("ROGUE", "192.168.10.21")


@pytest.mark.parametrize("content, message", [
    ("not json", r"is not JSON"),
    ('{"modalities": {}}', r"must hold \{\"modalities\".*at least one modality"),
    ('{"carm_a": {"ae_title": "CARM_A"}}', r"must hold \{\"modalities\""),
    ('{"modalities": {"carm_a": {"aet": "CARM_A"}}}', r"modality 'carm_a' must be \{\"ae_title\""),
    ('{"modalities": {"carm_a": {"ae_title": "CARM_A", "host": "carm.local"}}}',
     r"modality 'carm_a': modality 'carm_a' host must be an IP address .* got 'carm.local'"),
    ('{"modalities": {"carm_a": {"ae_title": "A_TITLE_OF_17_CHR"}}}', r"ae_title must be 1-16 ASCII characters"),
    ('{"modalities": {"carm_a": {"ae_title": "CARM_A", "port": 0}}}', r"port must be an integer in 1..65535"),
])
def test_a_bad_modalities_file_is_refused_naming_the_file_and_the_entry(tmp_path, content, message):
    path = tmp_path / "modalities.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message) as err:
        load_modalities(path)
    assert str(path) in str(err.value)
    with pytest.raises(FileNotFoundError, match=r"modalities file '.*missing.json': no such file"):
        load_modalities(tmp_path / "missing.json")


def test_bad_allow_arguments_are_refused_naming_them(views, tmp_path):
    out = tmp_path / "p.jsonl"
    with pytest.raises(ValueError, match=r"modality 'CARM_A@carm' host must be an IP address .* got 'carm'"):
        ReceiverConfig(output_path=out, allow=["CARM_A@carm"])
    with pytest.raises(ValueError, match=r"allow must be None, an AllowList, or Modality objects .* got \[\]"):
        ReceiverConfig(output_path=out, allow=[])
    with pytest.raises(ValueError, match=r"allow must be 'AE_TITLE' or 'AE_TITLE@IP_ADDRESS', got ' '"):
        parse_allow(" ")
    with pytest.raises(ValueError, match="modality 'x' ae_title must be 1-16 ASCII"):
        Modality("x", "")
    assert not out.exists()


def test_an_address_in_use_is_an_error_naming_it_and_no_file_is_created(views, tmp_path):
    """Before the output is opened: start() (and listen(), before the receiver is made) raise an
    OSError naming the host and port; no poses.jsonl, no pose worker left running."""
    workers = {t for t in threading.enumerate() if t.name == "histostudy-pose-worker"}
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        receiver = FrameReceiver(views, ReceiverConfig(output_path=tmp_path / "poses.jsonl", port=port))
        with pytest.raises(OSError, match=rf"cannot listen on 127.0.0.1:{port}: .*in use \(another receiver"):
            receiver.start()
        with pytest.raises(OSError, match=rf"cannot listen on 127.0.0.1:{port}: .*in use") as err:
            listen(views, ReceiverConfig(output_path=tmp_path / "listen.jsonl", port=port), timeout_s=1)
    assert err.value.errno == errno.EADDRINUSE
    assert not (tmp_path / "poses.jsonl").exists() and not (tmp_path / "listen.jsonl").exists()
    assert {t for t in threading.enumerate() if t.name == "histostudy-pose-worker"} <= workers
    with pytest.raises(RuntimeError, match="started already; make a new one"):
        receiver.start()


def _churn(port: int, n_peers: int, seconds: float) -> None:
    """``n_peers`` threads that, for ``seconds``, hold the receiver's connections as a port scanner
    and a flood of strangers would: half connect and send nothing (for 5 s at a time), half ask for an
    association as an AE off the list (rejected) and connect again. Run in its own process, so that
    its threads do not take the receiver's share of the GIL."""
    import time as _time

    from receiver_stub import associate_rq, read_pdu

    stop = _time.monotonic() + seconds

    def idle() -> None:
        while _time.monotonic() < stop:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                    sock.recv(1)  # held until its 5 s timeout
            except OSError:
                _time.sleep(0.05)

    def stranger() -> None:
        while _time.monotonic() < stop:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
                    sock.sendall(associate_rq(calling="STRANGER"))
                    read_pdu(sock)
            except OSError:
                _time.sleep(0.05)

    threads = [threading.Thread(target=idle if k % 2 else stranger, daemon=True) for k in range(n_peers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 10)


@pytest.mark.slow
def test_the_allow_listed_c_arm_is_not_turned_away_while_100_peers_churn(views, tmp_path):
    """100 loopback peers, half holding connections open without a word and half asking for
    associations as strangers, again and again: each of 10 C-ECHO associations of the C-arm on the
    allow-list is accepted (issue 56). Before, 12 idle connections were enough to turn it away
    (pynetdicom counted them among its 10 associations at once), and a burst of connections filled
    the listening backlog of 5, so that the kernel dropped the C-arm's SYN (retried after 1, 3, 7 s).
    The silent peers and the strangers are turned away on their connection's thread before
    pynetdicom starts an association's threads (each polls every millisecond; when they did, under
    this churn on 2 cores an association took 1.5 to 6 s)."""
    import multiprocessing
    import time

    tracker = StubTracker()
    with receiver_with(views, tmp_path, tracker, allow=["CARM@127.0.0.1"]) as receiver:
        churn = multiprocessing.get_context("fork").Process(target=_churn, args=(receiver.port, 100, 10.0))
        churn.start()
        try:
            time.sleep(2.5)  # the churn under way: idle connections held past the first-PDU wait
            waits = []
            while churn.is_alive() and len(waits) < 10:
                t0 = time.monotonic()
                established, reason = echo_from("127.0.0.1", receiver.port, "CARM")
                waits.append(time.monotonic() - t0)
                assert established, f"the C-arm was rejected (reason {reason}) after {waits[-1]:.2f} s"
        finally:
            churn.join(30)
            if churn.is_alive():
                churn.kill()
        stats = receiver.stats()
    # issue 56's 1 s holds with the machine otherwise busy (0.22 to 0.48 s, both cores taken by
    # another run); beside a whole test suite on 2 cores it took 0.51 to 1.14 s: bounded at 3 s here
    assert len(waits) == 10 and max(waits) < 3.0, f"C-ECHO associations took {sorted(waits)}"
    assert stats["associations_rejected"] > 50 and stats["connections_silent"] > 20
    assert stats["connections"] > stats["associations_rejected"] + stats["connections_silent"]

