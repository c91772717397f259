"""The link to one UR controller through ur_rtde (§II-C): its receive and control interfaces, every
blocking call under a watchdog, and a connection declared lost rather than trusted (docs/robot.md,
"The RTDE client"). Timeouts in seconds."""

from __future__ import annotations

import socket
import threading
import time
from typing import Any

from ..base import RobotConnectionError, RobotError, RobotTimeout

__all__ = ["RTDEConnection"]

RTDE_PORT = 30004
DASHBOARD_PORT = 29999

# Client objects whose call was abandoned by the watchdog: kept alive so that no destructor runs
# while a blocked call still uses them.
_ABANDONED: list = []


def _quiet_disconnect(iface) -> None:
    try:
        iface.disconnect()
    except RuntimeError:
        pass


def probe_port(host: str, port: int, timeout_s: float) -> None:
    """A bounded TCP connect to ``host:port``; RobotConnectionError if nothing answers."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise RobotConnectionError(
            f"cannot reach a UR controller at {host}:{port} within {timeout_s} s ({exc}); "
            f"check the robot's IP, that it is powered on and in remote control"
        ) from None


class RTDEConnection:
    """ur_rtde's receive and control interfaces to the controller at ``host``, guarded (module docstring).

    ``command_timeout_s``: watchdog of every non-motion call; ``connect_timeout_s``: port probe;
    ``settle_timeout_s``: waiting for fresh data; ``frequency_hz``: RTDE frequency (-1: the
    client's default). Not connected until :meth:`connect`.
    """

    def __init__(self, host: str, *, command_timeout_s: float, connect_timeout_s: float, settle_timeout_s: float,
                 frequency_hz: float):
        self.host = host
        self.command_timeout_s = float(command_timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.settle_timeout_s = float(settle_timeout_s)
        self.frequency_hz = float(frequency_hz)
        # ur_rtde's RTDEControlInterface and RTDEReceiveInterface once connected (ur_rtde has no types)
        self._control: Any = None
        self._receive: Any = None
        self._lost_reason: str | None = "not connected yet"
        self._inflight: threading.Thread | None = None

    def connect(self) -> None:
        """Open the receive and control interfaces (the control script is uploaded by ur_rtde)."""
        import rtde_control
        import rtde_receive

        if self._control is not None:
            return
        probe_port(self.host, RTDE_PORT, self.connect_timeout_s)
        probe_port(self.host, DASHBOARD_PORT, self.connect_timeout_s)
        try:
            receive = rtde_receive.RTDEReceiveInterface(self.host, self.frequency_hz)
        except RuntimeError as exc:
            raise RobotConnectionError(f"ur_rtde could not connect to {self.host}: {exc}") from None
        try:
            control = rtde_control.RTDEControlInterface(self.host, self.frequency_hz)
        except RuntimeError as exc:
            _quiet_disconnect(receive)
            _ABANDONED.append((None, receive))
            raise RobotConnectionError(f"ur_rtde could not start its control script on {self.host}: {exc}") from None
        self._receive, self._control = receive, control
        self._lost_reason = None

    def reconnect(self) -> None:
        """Drop the current interfaces (if any) and connect afresh (after a drop, timeout or stop)."""
        self._abandon("reconnecting")
        self._lost_reason = "reconnecting"
        self.connect()

    def close(self) -> None:
        """Stop the control script and disconnect (idempotent; never raises for a lost link)."""
        if self._control is None:
            return
        if self._is_connected():
            try:
                self._call("stopScript", self._control.stopScript, timeout_s=self.command_timeout_s)
            except RobotError:
                pass
        self._abandon("closed by the caller")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _abandon(self, reason: str) -> None:
        """Give up the current interfaces: disconnect them (or, if a call still blocks in one, keep it)."""
        control, receive = self._control, self._receive
        self._control = self._receive = None
        self._lost_reason = reason
        if control is None and receive is None:
            return
        _ABANDONED.append((control, receive))
        inflight = self._inflight
        if inflight is not None and inflight.is_alive():
            inflight.join(timeout=1.0)
        if inflight is not None and inflight.is_alive():
            return  # disconnecting under a blocked call is unsafe; the objects stay referenced
        # A dropped interface keeps reconnecting in the background (it would attach to the next
        # controller on this address): disconnect it. This releases the GIL and takes ~0.5 s, so
        # both interfaces are disconnected in parallel. In parallel, not one after the other: after
        # a drop the control interface's own thread reconnects (ur_rtde 1.6.5), and the later its
        # disconnect comes, the likelier it races that. Measured on the simulated controller's
        # drop mid-move: receive then control in turn crashed the process in 5 of 6 runs of
        # tests/robot/test_robot_rtde.py, control then receive let the old control interface
        # reconnect and take the arm over in 1 of 6; in parallel 0 of 35.
        workers = [
            threading.Thread(target=_quiet_disconnect, args=(iface,), daemon=True)
            for iface in (control, receive)
            if iface is not None
        ]
        for w in workers:
            w.start()
        for w in workers:
            w.join(timeout=2.0)

    def _is_connected(self) -> bool:
        if self._control is None or self._receive is None:
            return False
        return bool(self._receive.isConnected()) and bool(self._control.isConnected())

    def _require_connected(self, what: str) -> None:
        if self._control is None:
            raise RobotConnectionError(
                f"{what}: not connected to the UR controller at {self.host} ({self._lost_reason}); call reconnect()"
            )
        if not self._is_connected():
            self._abandon("the connection dropped")
            raise RobotConnectionError(
                f"{what}: the connection to the UR controller at {self.host} dropped; no pose is read "
                f"(ur_rtde would return the last one); call reconnect()"
            )

    def _call(self, name: str, fn, *args, timeout_s: float):
        """Run a blocking ur_rtde call under a watchdog; the connection is lost if it expires or drops."""
        box: dict = {}
        receive = self._receive

        def target():
            try:
                box["value"] = fn(*args)
            except BaseException as exc:  # re-raised in the caller's thread
                box["error"] = exc

        worker = threading.Thread(target=target, name=f"ur_rtde {name}", daemon=True)
        t0 = time.monotonic()
        self._inflight = worker
        worker.start()
        while True:
            worker.join(timeout=0.01)
            if not worker.is_alive():
                break
            if receive is not None and not receive.isConnected():
                self._abandon(f"the connection dropped during {name}")
                raise RobotConnectionError(
                    f"{name}: the connection to the UR controller at {self.host} dropped during the call; "
                    f"the arm's pose is unknown until reconnect()"
                )
            if time.monotonic() - t0 > timeout_s:
                self._abandon(f"{name} timed out")
                raise RobotTimeout(
                    f"{name}: no answer from the UR controller at {self.host} within {timeout_s:.3g} s; "
                    f"the connection is considered lost and the arm's state unknown until reconnect()"
                )
        if "error" in box:
            exc = box["error"]
            if isinstance(exc, RuntimeError):
                raise RobotConnectionError(f"{name}: ur_rtde failed: {exc}") from None
            raise exc
        return box.get("value")

    def _wait_fresh_data(self, what: str, packets: int = 2) -> None:
        """Wait (bounded) until the receive interface got ``packets`` newer packets than it has now.

        A packet in flight when a command completed may predate it; the second newer one cannot.
        """
        t0 = time.monotonic()
        seen = self._receive.getTimestamp()
        advances = 0
        while advances < packets:
            now = self._receive.getTimestamp()
            if now > seen:
                seen, advances = now, advances + 1
                continue
            self._require_connected(what)
            if time.monotonic() - t0 > self.settle_timeout_s:
                raise RobotTimeout(f"{what}: no fresh data from the UR controller at {self.host} "
                                   f"in {self.settle_timeout_s} s")
            time.sleep(0.001)
