"""The simulated UR controller's servers (§II-C): dashboard, RTDE and script sockets on a loopback address,
each client on a thread of its own, over a :class:`ControlProgram` and its :class:`ControllerArm`."""

from __future__ import annotations

import ipaddress
import os
import socket
import struct
import sys
import threading
import time

from ..sim import FaultPlan, SimulatedUR5e
from ._arm import ControllerArm
from ._program import ControlProgram
from ._protocol import (
    CONTROLLER_VERSION,
    DASHBOARD_PORT,
    POLYSCOPE_VERSION_LINE,
    RTDE_PORT,
    RTDE_PROTOCOL_VERSION,
    RUNTIME_PLAYING,
    SCRIPT_PORT,
    SERIAL_NUMBER,
    STREAM_PERIOD_S,
    RTDERecipe,
    recv_exact,
    rtde_packet,
)

__all__ = ["SimulatedController"]


class SimulatedController:
    """The controller's servers over its program and arm; see the module docstring.

    ``sim``: the arm; ``faults``: what to inject (default none); ``time_scale``: wall seconds per
    simulated second of motion (0: moves end at once). Call :meth:`start`, then
    :meth:`serve_forever` or :meth:`close`.
    """

    def __init__(
        self,
        host: str,
        sim: SimulatedUR5e,
        faults: FaultPlan | None = None,
        time_scale: float = 0.0,
        verbose: bool = False,
    ):
        addr = ipaddress.ip_address(host)
        if not addr.is_loopback:
            raise ValueError(f"host must be a loopback address (127.0.0.0/8 or ::1), got {host!r}")
        self.host = host
        self.verbose = verbose
        self.shutdown = threading.Event()
        self.arm = ControllerArm(
            sim,
            faults if faults is not None else FaultPlan(),
            time_scale,
            shutdown=self.shutdown,
            log=self.log,
            on_disconnect=self.drop_connections,
        )
        self.program = ControlProgram(self.arm, shutdown=self.shutdown, log=self.log,
                                      on_disconnect=self.drop_connections)
        self.lock = self.arm.lock
        self.changed = self.arm.changed
        self.clients: set[socket.socket] = set()
        self.listeners: list[socket.socket] = []

    @property
    def sim(self) -> SimulatedUR5e:
        return self.arm.sim

    def values(self) -> dict:
        """Every output field's current value (SI units and axis-angle at this boundary)."""
        return self.program.values()

    # -- bookkeeping ---------------------------------------------------------------------------
    def log(self, *parts) -> None:
        if self.verbose:
            print(f"[controller {self.host}]", *parts, file=sys.stderr, flush=True)

    def _register_client(self, sock: socket.socket) -> None:
        with self.lock:
            self.clients.add(sock)

    def _forget_client(self, sock: socket.socket) -> None:
        with self.lock:
            self.clients.discard(sock)
        try:
            sock.close()
        except OSError:
            pass

    def drop_connections(self, why: str) -> None:
        """Simulate a network drop: stop the arm, close every client socket, keep listening."""
        self.log("dropping all connections:", why)
        self.arm.stop_motion()
        with self.lock:
            clients = list(self.clients)
            self.clients.clear()
            self.program.busy = False
        for s in clients:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            try:
                s.close()
            except OSError:
                pass
        self.arm.notify()

    # -- servers -------------------------------------------------------------------------------
    def _listen(self, port: int, handler) -> None:
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind((self.host, port))
        srv.listen(8)
        srv.settimeout(0.2)
        self.listeners.append(srv)

        def accept_loop():
            while not self.shutdown.is_set():
                try:
                    conn, _ = srv.accept()
                except TimeoutError:
                    continue
                except OSError:
                    return
                conn.settimeout(None)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._register_client(conn)
                threading.Thread(target=self._guard, args=(handler, conn), daemon=True).start()

        threading.Thread(target=accept_loop, daemon=True).start()

    def _guard(self, handler, conn: socket.socket) -> None:
        try:
            handler(conn)
        except (OSError, ConnectionError, struct.error, ValueError, UnicodeDecodeError) as exc:
            self.log(f"{handler.__name__}: connection ended: {exc!r}")
        finally:
            self._forget_client(conn)

    def _dashboard(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        while not self.shutdown.is_set():
            chunk = conn.recv(4096)
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = self.dashboard_reply(line.decode("utf-8", "replace").strip())
                if reply is None:
                    conn.sendall(b"Disconnected\n")
                    return
                conn.sendall(reply.encode() + b"\n")

    def dashboard_reply(self, line: str) -> str | None:
        """The dashboard server's answer to one command line (None: close the connection)."""
        cmd = line.lower()
        with self.lock:
            pstop = self.sim.state().protective_stop
            playing = self.program.runtime_state == RUNTIME_PLAYING
        if cmd == "polyscopeversion":
            return POLYSCOPE_VERSION_LINE
        if cmd == "get serial number":
            return SERIAL_NUMBER
        if cmd == "is in remote control":
            return "true"
        if cmd == "unlock protective stop":
            self.arm.clear_protective_stop()
            return "Protective stop releasing"
        if cmd == "close safety popup":
            return "closing safety popup"
        if cmd == "robotmode":
            return "Robotmode: RUNNING"
        if cmd in ("safetystatus", "safetymode"):
            return ("Safetystatus: " if cmd == "safetystatus" else "Safetymode: ") + (
                "PROTECTIVE_STOP" if pstop else "NORMAL"
            )
        if cmd == "programstate":
            return "PLAYING rtde_control" if playing else "STOPPED <unnamed>"
        if cmd == "running":
            return f"Program running: {'true' if playing else 'false'}"
        if cmd == "stop":
            self.program.stop_script()
            return "Stopped"
        if cmd in ("quit", "shutdown"):
            return None
        return f"could not understand: '{line}'"

    def _script(self, conn: socket.socket) -> None:
        # A script ends with a final "end" line; wait briefly after one in case more follows.
        data = b""
        conn.settimeout(None)
        while not self.shutdown.is_set():
            if data.rstrip().endswith(b"end"):
                conn.settimeout(0.05)
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                chunk = None
            if chunk:
                data += chunk
                continue
            if data:
                self.log(f"script received ({len(data)} bytes)")
                if b"def rtde_control" in data:
                    self.program.start_script()
                data = b""
            if chunk == b"":
                return
            conn.settimeout(None)

    def _rtde(self, conn: socket.socket) -> None:
        send_lock = threading.Lock()
        outputs: list[RTDERecipe] = []
        inputs: dict[int, RTDERecipe] = {}
        streaming = threading.Event()

        def send(ptype: str, payload: bytes = b"") -> None:
            with send_lock:
                conn.sendall(rtde_packet(ptype, payload))

        def stream():
            while not self.shutdown.is_set():
                with self.changed:
                    self.changed.wait(timeout=STREAM_PERIOD_S)
                vals = self.values()
                try:
                    for r in list(outputs):
                        send("U", r.pack(vals))
                except OSError:
                    return

        try:
            self._rtde_loop(conn, send, outputs, inputs, streaming, stream)
        finally:
            if inputs:
                # The control client is gone: like a program whose operator left, stop it and the arm.
                self.log("control client disconnected: stopping the program")
                self.program.stop_script()

    def _rtde_loop(self, conn, send, outputs, inputs, streaming, stream) -> None:
        while not self.shutdown.is_set():
            size, ptype = struct.unpack(">HB", recv_exact(conn, 3))
            payload = recv_exact(conn, size - 3) if size > 3 else b""
            t = chr(ptype)
            if t == "U":
                recipe = inputs.get(payload[0])
                if recipe is None:
                    self.log(f"input packet for unknown recipe {payload[0]}")
                    continue
                self.program.on_inputs(recipe.unpack(payload))
            elif t == "V":
                (version,) = struct.unpack(">H", payload[:2])
                send("V", bytes([1 if version == RTDE_PROTOCOL_VERSION else 0]))
            elif t == "v":
                send("v", struct.pack(">IIII", *CONTROLLER_VERSION))
            elif t == "O":
                (freq,) = struct.unpack(">d", payload[:8])
                names = [n for n in payload[8:].decode().split(",") if n]
                recipe = RTDERecipe(len(outputs) + 1, names)
                self.log(f"output recipe {recipe.id} at {freq:g} Hz: {len(names)} fields")
                if recipe.valid:
                    outputs.append(recipe)
                    send("O", bytes([recipe.id]) + ",".join(recipe.types).encode())
                else:
                    send("O", bytes([0]) + ",".join(recipe.types).encode())
            elif t == "I":
                names = [n for n in payload.decode().split(",") if n]
                recipe = RTDERecipe(len(inputs) + 1, names)
                if recipe.valid:
                    inputs[recipe.id] = recipe
                    send("I", bytes([recipe.id]) + ",".join(recipe.types).encode())
                else:
                    send("I", bytes([0]) + ",".join(recipe.types).encode())
            elif t == "S":
                send("S", b"\x01")
                if not streaming.is_set():
                    streaming.set()
                    threading.Thread(target=stream, daemon=True).start()
            elif t == "P":
                send("P", b"\x01")
            else:
                self.log(f"unhandled RTDE packet type {t!r}")

    def start(self) -> None:
        """Bind the three ports on the host and start serving (returns at once)."""
        self._listen(DASHBOARD_PORT, self._dashboard)
        self._listen(RTDE_PORT, self._rtde)
        self._listen(SCRIPT_PORT, self._script)
        threading.Thread(target=self.program.command_worker, daemon=True).start()

    def close(self) -> None:
        """Stop serving: drop every client, stop the arm, close the listeners."""
        self.shutdown.set()
        self.drop_connections("controller shutting down")
        for s in self.listeners:
            try:
                s.close()
            except OSError:
                pass

    def serve_forever(self, max_lifetime_s: float, parent_pid: int | None = None) -> None:
        """Serve until :attr:`shutdown` is set, ``max_lifetime_s`` has passed or ``parent_pid`` is gone; then close."""
        deadline = time.monotonic() + max_lifetime_s
        while not self.shutdown.is_set() and time.monotonic() < deadline:
            if parent_pid is not None and not _pid_alive(parent_pid):
                break
            self.shutdown.wait(0.2)
        self.close()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
