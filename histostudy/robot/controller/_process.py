"""The simulated UR controller's command line (``python -m histostudy.robot.controller``) and the child
process that runs it (:class:`ControllerProcess`), served on a loopback address to the unmodified
ur_rtde client (§II-C; docs/robot.md, "The simulated UR controller")."""

from __future__ import annotations

import argparse
import ipaddress
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

from ..base import Workspace
from ..sim import HOME_JOINTS_RAD, FaultPlan, SimulatedUR5e
from ._protocol import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT, Command
from ._server import SimulatedController

__all__ = ["Command", "ControllerProcess", "SimulatedController", "main", "DASHBOARD_PORT", "RTDE_PORT", "SCRIPT_PORT"]


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m histostudy.robot.controller",
        description="Simulated UR5e controller (dashboard 29999, RTDE 30004, script 30003) on a loopback address.",
    )
    p.add_argument("--host", default="127.0.0.1", help="loopback address to serve on (127.0.0.0/8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the repeatability noise")
    p.add_argument("--repeatability-mm", type=float, default=0.03, help="landing noise radius in mm (0: none)")
    p.add_argument("--time-scale", type=float, default=0.0, help="wall seconds per simulated second of motion")
    p.add_argument("--initial-joints", type=float, nargs=6, default=list(HOME_JOINTS_RAD), metavar="Q_RAD",
                   help="start configuration in rad")
    p.add_argument("--workspace-box", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="safety box of the TCP in the base frame, mm (the controller's safety limits)")
    p.add_argument("--disconnect-after-moves", type=_positive_int, default=None, metavar="K",
                   help="drop every connection after move K (at the next command)")
    p.add_argument("--disconnect-during-move", type=_positive_int, default=None, metavar="K",
                   help="drop every connection halfway through move K")
    p.add_argument("--protective-stop-during-move", type=_positive_int, default=None, metavar="K",
                   help="protective stop halfway through move K")
    p.add_argument("--command-delay-s", type=float, default=0.0,
                   help="answer every command this late (slow controller)")
    p.add_argument("--max-lifetime-s", type=float, default=3600.0, help="exit after this many seconds")
    p.add_argument("--parent-pid", type=int, default=None, help="exit when this process is gone")
    p.add_argument("--verbose", action="store_true")
    p.add_argument("--detach", action="store_true",
                   help="start the controller in the background, wait until its ports accept connections, print "
                        "its process id on stdout and return (stop it with kill PID; it exits by itself after "
                        "--max-lifetime-s)")
    return p


def main(argv=None) -> int:
    """The command line ``python -m histostudy.robot.controller``: serve a simulated UR controller.

    Args:
        argv: the arguments (``--help`` lists them); None reads ``sys.argv``.

    Returns:
        The exit status: 0 after serving, 2 when it cannot serve (a bad address or argument, a port
        in use); with ``--detach``, that of starting the controller in the background.
    """
    args = build_parser().parse_args(argv)
    if args.detach:
        return _detach(list(sys.argv[1:] if argv is None else argv))
    try:
        workspace = Workspace()
        if args.workspace_box is not None:
            workspace = Workspace(lower_mm=tuple(args.workspace_box[:3]), upper_mm=tuple(args.workspace_box[3:]))
        faults = FaultPlan(
            disconnect_after_moves=args.disconnect_after_moves,
            disconnect_during_move=args.disconnect_during_move,
            protective_stop_during_move=args.protective_stop_during_move,
            command_delay_s=args.command_delay_s,
        )
        sim = SimulatedUR5e(
            args.seed,
            repeatability_mm=args.repeatability_mm,
            initial_joints_rad=args.initial_joints,
            workspace=workspace,
        )
        ctrl = SimulatedController(args.host, sim, faults, time_scale=args.time_scale, verbose=args.verbose)
        ctrl.start()
    except (ValueError, OSError) as exc:
        print(f"simulated UR controller: cannot serve on {args.host!r}: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: ctrl.shutdown.set())
    print(f"simulated UR controller ready on {args.host} (ports {DASHBOARD_PORT}, {RTDE_PORT}, {SCRIPT_PORT})",
          flush=True)
    try:
        ctrl.serve_forever(args.max_lifetime_s, args.parent_pid)
    except KeyboardInterrupt:
        ctrl.close()
    return 0


def _detach(argv: list[str]) -> int:
    """``--detach``: the same command line without it, in a new session that outlives this process;
    its pid on stdout once it serves."""
    rest = [a for a in argv if a != "--detach"]
    host = rest[rest.index("--host") + 1] if "--host" in rest else "127.0.0.1"
    try:
        child = ControllerProcess(host, *rest, tied_to_parent=False, max_lifetime_s=3600.0)
    except (ValueError, RuntimeError, TimeoutError) as exc:
        print(f"simulated UR controller: {exc}", file=sys.stderr)
        return 2
    print(child.proc.pid, flush=True)
    return 0


class ControllerProcess:
    """The simulated UR controller in a child process (for tests, benchmarks and notebooks; §II-C).

    ``ControllerProcess("127.0.0.2", "--repeatability-mm", "0")`` starts
    ``python -m histostudy.robot.controller --host 127.0.0.2 ...`` and waits until its three ports
    accept connections. Use as a context manager or call :meth:`stop`; :meth:`kill` simulates a
    crashed controller (SIGKILL).

    Args:
        host: a loopback address (127.0.0.0/8): one address per controller, the client's ports being
            fixed.
        *args: further command-line arguments of the controller (``--help`` lists them).
        start_timeout_s: how long to wait for the ports, s.
        max_lifetime_s: the controller exits after this long, s.
        tied_to_parent: the controller exits when this process is gone; False: it runs in a session
            of its own until stopped or ``max_lifetime_s`` (``--detach``).

    Raises:
        ValueError: ``host`` is not a loopback address.
        RuntimeError: the controller exited while starting (its output in the message).
        TimeoutError: its ports did not open within ``start_timeout_s``.
    """

    def __init__(self, host: str, *args: str, start_timeout_s: float = 20.0, max_lifetime_s: float = 600.0,
                 tied_to_parent: bool = True):
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"host must be a loopback address (127.0.0.0/8), got {host!r}")
        self.host = host
        argv = [str(a) for a in args]
        if "--host" in argv:  # the host given twice (--detach passes its command line on): the one checked above
            i = argv.index("--host")
            del argv[i:i + 2]
        tie = ["--parent-pid", str(os.getpid())] if tied_to_parent else []
        cmd = [sys.executable, "-m", "histostudy.robot.controller", "--host", host,
               "--max-lifetime-s", str(max_lifetime_s), *tie, *argv]
        # A file, not a pipe, for the log: a full pipe would block the controller.
        self.log = tempfile.TemporaryFile(mode="w+t")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, text=True,
                                     start_new_session=not tied_to_parent)
        deadline = time.monotonic() + start_timeout_s
        pending = [DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT]
        while pending:
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"simulated controller on {host} exited with status {self.proc.returncode}: {self.output().strip()}"
                )
            if time.monotonic() > deadline:
                self.kill()
                raise TimeoutError(f"simulated controller on {host} did not open ports {pending} "
                                   f"within {start_timeout_s} s")
            try:
                with socket.create_connection((host, pending[0]), timeout=0.2):
                    pass
            except OSError:
                time.sleep(0.05)
                continue
            pending.pop(0)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, timeout_s: float = 5.0) -> None:
        """Terminate (SIGTERM), escalating to SIGKILL after ``timeout_s``; idempotent."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout_s)

    def kill(self) -> None:
        """SIGKILL: the controller vanishes without closing anything itself (a crash, a pulled cable)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5.0)

    def output(self) -> str:
        """What the controller printed so far (its log with --verbose)."""
        self.log.flush()
        self.log.seek(0)
        return self.log.read()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()

