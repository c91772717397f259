"""Fixtures the receiver's tests share (tests/lab/): ``tls_files``, the PEM files of a test PKI.
Loading this file puts tests/lab on sys.path (pytest's default "prepend" import mode), so the
tests import receiver_stub.py."""

import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest


def _openssl(*args: str, cwd: Path) -> None:
    done = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


@pytest.fixture(scope="session")
def tls_files(tmp_path_factory):
    """A test CA; a server certificate it signed for 127.0.0.1 and localhost, and a client's; and a
    "rogue" client's certificate that another CA signed (self-signed). Paths: ``ca``,
    ``server_cert``, ``server_key``, ``client_cert``, ``client_key``, ``rogue_cert``,
    ``rogue_key``. Made with the ``openssl`` command (skipped without it)."""
    if not shutil.which("openssl"):
        pytest.skip("the openssl command is not installed")
    folder = tmp_path_factory.mktemp("pki")
    key = ("-newkey", "rsa:2048", "-nodes")
    _openssl("req", "-x509", *key, "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj",
             "/CN=histostudy test CA", cwd=folder)
    for who in ("server", "client"):
        (folder / f"{who}.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
        _openssl("req", *key, "-keyout", f"{who}.key", "-out", f"{who}.csr", "-subj", f"/CN=histostudy test {who}",
                 cwd=folder)
        _openssl("x509", "-req", "-in", f"{who}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{who}.pem", "-days", "2", "-extfile", f"{who}.ext", cwd=folder)
    _openssl("req", "-x509", *key, "-keyout", "rogue.key", "-out", "rogue.pem", "-days", "2", "-subj",
             "/CN=histostudy rogue client", cwd=folder)
    return SimpleNamespace(ca=folder / "ca.pem", server_cert=folder / "server.pem", server_key=folder / "server.key",
                           client_cert=folder / "client.pem", client_key=folder / "client.key",
                           rogue_cert=folder / "rogue.pem", rogue_key=folder / "rogue.key")
