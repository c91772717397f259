"""Tests of the live receiver over TLS (histostudy.lab.tls): the same pose lines as over plain TCP,
a client whose certificate the CA did not sign (or without one) refused during the handshake, a
silent client that holds no other sender, and DCMTK's ``storescu +tls`` where it is installed.

The certificates are conftest.py's ``tls_files`` (a test CA made with openssl); the pose work is
receiver_stub.py's stub tracker, whose "pose" carries the means of the pixels it was given.
"""

import logging
import shutil
import socket
import ssl
import subprocess

import numpy as np
import pytest
from receiver_stub import StubTracker, pair_objects, read_lines, receiver_with, small_views, wait_for_count

from histostudy.lab import TLSConfig, send_frames

N_PAIRS = 3


@pytest.fixture(scope="module")
def views():
    return small_views()


def server_tls(files, ca=True) -> TLSConfig:
    return TLSConfig(files.server_cert, files.server_key, files.ca if ca else None)


def client_tls(files, who="client") -> TLSConfig:
    cert = None if who is None else getattr(files, f"{who}_cert")
    key = None if who is None else getattr(files, f"{who}_key")
    return TLSConfig(cert, key, files.ca)


def receive(views, folder, objects, send, **options) -> tuple[list, StubTracker, dict]:
    """The lines written, the tracker's images and the stats of a receiver (``options``) that
    ``send(port)`` sent ``objects`` to (every pair posed)."""
    folder.mkdir()
    tracker = StubTracker()
    with receiver_with(views, folder, tracker, max_queued_pairs=None, **options) as receiver:
        assert send(receiver.port) == [0] * len(objects)
        assert receiver.wait_for_pairs(len(objects) // 2, timeout_s=30)
    return read_lines(folder / "poses.jsonl"), tracker, receiver.stats()


def without_times(lines: list) -> list:
    return [{k: v for k, v in line.items() if k != "seconds"} for line in lines]


@pytest.mark.parametrize("client", ["send_frames", "storescu"])
def test_poses_over_tls_are_those_over_tcp(views, tmp_path, tls_files, client):
    """The same pairs sent over plain TCP and over TLS with client certificates (mutual
    authentication): the same lines (times aside) and bit-for-bit the same pixels posed."""
    if client == "storescu" and "+tls" not in _storescu_help():
        pytest.skip("DCMTK's storescu is not installed, or built without TLS")
    objects = [ds for k in range(N_PAIRS) for ds in pair_objects(views, k)]
    paths = []
    for i, ds in enumerate(objects):
        paths.append(tmp_path / f"{i}.dcm")
        ds.save_as(paths[-1], enforce_file_format=True)

    def by_storescu(port):
        done = _storescu_tls(port, tls_files, "client", paths)
        assert done.returncode == 0, done.stderr
        return [0] * len(paths)

    def by_send_frames(port):
        return send_frames(paths, "127.0.0.1", port, tls=client_tls(tls_files))

    tcp_lines, tcp_tracker, _ = receive(views, tmp_path / "tcp", objects,
                                        lambda port: send_frames(paths, "127.0.0.1", port))
    tls_lines, tls_tracker, stats = receive(views, tmp_path / "tls", objects,
                                            by_storescu if client == "storescu" else by_send_frames,
                                            tls=server_tls(tls_files))
    assert [line["pair_index"] for line in tls_lines] == list(range(N_PAIRS))
    assert without_times(tls_lines) == without_times(tcp_lines)
    assert len(tls_tracker.images) == N_PAIRS
    for a, b in zip(tls_tracker.images, tcp_tracker.images):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert (stats["tls_refused"], stats["associations"], stats["objects_received"]) == (0, 1, 2 * N_PAIRS)


@pytest.mark.parametrize("who", ["rogue", None], ids=["other_ca", "no_certificate"])
def test_a_client_without_a_certificate_the_ca_signed_is_refused(views, tmp_path, tls_files, who, caplog):
    """Refused in the handshake, before any DICOM: no association, nothing read or posed, counted
    and logged; the receiver goes on serving the client with a good certificate."""
    tracker = StubTracker()
    with caplog.at_level(logging.WARNING, logger="histostudy.lab.receiver"), \
            receiver_with(views, tmp_path, tracker, tls=server_tls(tls_files)) as receiver:
        with pytest.raises(ConnectionError, match=r"over TLS .*(aborted|refused the TLS handshake)"):
            send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, tls=client_tls(tls_files, who),
                        timeout_s=10)
        stats = wait_for_count(receiver, "tls_refused", 1)
        assert (stats["tls_refused"], stats["associations"], stats["objects_received"]) == (1, 0, 0)
        assert read_lines(tmp_path / "poses.jsonl") == [] and tracker.images == []
        assert send_frames(pair_objects(views, 1), "127.0.0.1", receiver.port, tls=client_tls(tls_files)) == [0, 0]
        assert receiver.wait_for_pairs(1, timeout_s=30)
    assert receiver.stats()["tls_refused"] == 1 and len(read_lines(tmp_path / "poses.jsonl")) == 1
    (refusal,) = [r.getMessage() for r in caplog.records if "refused a TLS connection" in r.getMessage()]
    assert refusal.startswith("refused a TLS connection from 127.0.0.1:")
    assert ("CERTIFICATE_VERIFY_FAILED" if who else "PEER_DID_NOT_RETURN_A_CERTIFICATE") in refusal


def test_storescu_with_a_certificate_of_another_ca_is_refused(views, tmp_path, tls_files):
    if "+tls" not in _storescu_help():
        pytest.skip("DCMTK's storescu is not installed, or built without TLS")
    path = tmp_path / "A.dcm"
    pair_objects(views, 0)[0].save_as(path, enforce_file_format=True)
    with receiver_with(views, tmp_path, StubTracker(), tls=server_tls(tls_files)) as receiver:
        done = _storescu_tls(receiver.port, tls_files, "rogue", [path])
        assert done.returncode != 0
        stats = wait_for_count(receiver, "tls_refused", 1)
    assert (stats["tls_refused"], stats["associations"], stats["objects_received"]) == (1, 0, 0)


def test_a_plain_tcp_client_and_a_silent_one_do_not_get_in_and_do_not_hold_the_others(views, tmp_path, tls_files):
    """A client that connects and says nothing holds only its own connection (its handshake runs on
    its own thread); a plain DICOM client is refused by the handshake; a TLS client then stores
    at once. Without a CA the receiver asks for no client certificate."""
    tracker = StubTracker()
    with receiver_with(views, tmp_path, tracker, tls=server_tls(tls_files, ca=False)) as receiver:
        with socket.create_connection(("127.0.0.1", receiver.port), timeout=5):
            with pytest.raises(ConnectionError):
                send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, timeout_s=5)
            anonymous = TLSConfig(ca=tls_files.ca)
            assert send_frames(pair_objects(views, 1), "127.0.0.1", receiver.port, tls=anonymous, timeout_s=5) \
                == [0, 0]
            assert receiver.wait_for_pairs(1, timeout_s=30)
    stats = receiver.stats()
    assert stats["tls_refused"] >= 1 and stats["associations"] == 1 and stats["objects_received"] == 2


def test_the_sender_checks_the_receivers_certificate(views, tmp_path, tls_files):
    """A sender trusting another CA, or calling the receiver by a name its certificate lacks, does not send."""
    with receiver_with(views, tmp_path, StubTracker(), tls=server_tls(tls_files, ca=False)) as receiver:
        with pytest.raises(ConnectionError, match="refused the TLS handshake"):
            send_frames(pair_objects(views, 0), "127.0.0.1", receiver.port, tls=TLSConfig(ca=tls_files.rogue_cert),
                        timeout_s=5)
        context = TLSConfig(ca=tls_files.ca).client_context()
        assert context.check_hostname and context.verify_mode == ssl.CERT_REQUIRED
    assert receiver.stats()["objects_received"] == 0


def test_tls_arguments_are_checked(views, tmp_path, tls_files):
    from histostudy.lab import ReceiverConfig

    with pytest.raises(FileNotFoundError, match=r"tls cert '.*missing.pem': no such file"):
        TLSConfig(tmp_path / "missing.pem", tls_files.server_key)
    with pytest.raises(ValueError, match="tls key .* was given without its certificate"):
        TLSConfig(key=tls_files.server_key)
    with pytest.raises(ValueError, match="tls cert must be given for the receiver"):
        ReceiverConfig(output_path=tmp_path / "p.jsonl", tls=TLSConfig(ca=tls_files.ca))
    with pytest.raises(ValueError, match=r"cannot be loaded .*PEM"):
        TLSConfig(tls_files.ca, tls_files.server_key).server_context()  # a key that is not the certificate's
    with pytest.raises(ValueError, match=r"tls must be an ssl.SSLContext for the server \(ssl.PROTOCOL_TLS_SERVER\)"):
        ReceiverConfig(output_path=tmp_path / "p.jsonl", tls=ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT))
    with pytest.raises(ValueError, match=r"tls must be None, a histostudy.lab.TLSConfig or an ssl.SSLContext"):
        send_frames(pair_objects(views, 0), "127.0.0.1", 104, tls="yes")
    assert not (tmp_path / "p.jsonl").exists()


def _storescu_help() -> str:
    if not shutil.which("storescu"):
        return ""
    return subprocess.run(["storescu", "--help"], capture_output=True, text=True, timeout=30).stdout


def _storescu_tls(port: int, files, who: str, paths) -> subprocess.CompletedProcess:
    """DCMTK's storescu over TLS with ``who``'s key and certificate, trusting the test CA."""
    key, cert = getattr(files, f"{who}_key"), getattr(files, f"{who}_cert")
    return subprocess.run(["storescu", "+tls", str(key), str(cert), "-pw", "+cf", str(files.ca), "-aec", "HISTOSTUDY",
                           "127.0.0.1", str(port), *map(str, paths)], capture_output=True, text=True, timeout=60)
