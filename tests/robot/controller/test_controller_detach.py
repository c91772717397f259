"""``python -m histostudy.robot.controller --detach`` (the README's lab block starts the simulated UR
controller so): it returns once the controller serves, printing the pid of a process that outlives
it in a session of its own, and that process is stopped by ``kill PID``."""

import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from histostudy.robot.controller._protocol import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT

HOST = "127.0.0.73"


def _wait_gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # exited but not reaped (no init process in a container): a zombie is gone too
            if " Z" in open(f"/proc/{pid}/stat").read().split(")", 1)[1][:3]:
                return True
        except OSError:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.slow
def test_detach_returns_once_serving_and_the_controller_stops_on_kill():
    done = subprocess.run([sys.executable, "-m", "histostudy.robot.controller", "--host", HOST, "--detach"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    pid = int(done.stdout.strip())
    try:
        assert os.getsid(pid) == pid != os.getsid(0)  # a session of its own: a closed terminal leaves it running
        for port in (DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT):  # serving when --detach returned
            socket.create_connection((HOST, port), timeout=1).close()
        os.kill(pid, signal.SIGTERM)
        assert _wait_gone(pid, 10), "the controller did not stop on SIGTERM"
    finally:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def test_detach_refuses_an_address_that_is_not_loopback():
    done = subprocess.run([sys.executable, "-m", "histostudy.robot.controller", "--host", "192.0.2.1", "--detach"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "loopback" in done.stderr and done.stdout == ""
