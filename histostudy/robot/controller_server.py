"""A simulated UR controller on loopback that the unmodified ``ur_rtde`` client (1.6.5) drives.

Run it in its own process (ur_rtde's constructors hold the GIL, so a server thread in the client's
process deadlocks)::

    python -m histostudy.robot.controller --host 127.0.0.1 [--seed 0] [--repeatability-mm 0.03]

It serves what ``rtde_control.RTDEControlInterface`` and ``rtde_receive.RTDEReceiveInterface``
need from a UR e-Series controller, backed by :class:`~histostudy.robot.sim.SimulatedUR5e`:

- Dashboard (port 29999): a welcome line, then one reply line per command line
  (``PolyscopeVersion``, ``get serial number``, ``is in remote control``,
  ``unlock protective stop`` …).
- RTDE (port 30004): frames of a big-endian uint16 size (3-byte header included) and a uint8
  type; protocol version 2, controller version 5.11.1.108318, output recipes (ids 1, 2, … per
  connection) streamed as ``U`` packets, input recipes (ids 1..N in the order requested).
- Script (port 30003): the client uploads its control script; once it arrives the "program" runs
  (runtime_state 2) and commands travel through registers: output int register 0 = 1 (ready);
  the client writes a command number to input int register 0 and parameters to input double
  registers; the controller executes it, writes results to output double registers 0-5 (booleans
  to output int register 1) and sets output int register 0 = 2 (done); the client writes 0 and the
  controller returns to ready.

Conversion between the client's metres/axis-angle vectors and the library's millimetres/4x4
transforms happens here (:func:`histostudy.robot.rtde.transform_from_pose` and back). The
protocol was implemented from observed client behaviour; no client code or script is copied.

``moveJ``, ``moveJ_IK`` and ``moveL_FK`` are executed as linear moves to the target pose (the robot
layer only needs linear moves). When the control client's connection closes, the program and any
motion stop, and commands still waiting (a slow controller) are dropped.

Faults (``--disconnect-after-moves K``, ``--disconnect-during-move K``,
``--protective-stop-during-move K``, ``--command-delay-s S``) follow
:class:`~histostudy.robot.sim.FaultPlan`. A dropped connection closes every client socket and
stops the arm; the listeners stay up, so clients can reconnect to the same state.

Only loopback addresses (127.0.0.0/8) are served. The process exits on SIGTERM, after
``--max-lifetime-s``, or when ``--parent-pid`` is gone.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
import queue
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from .base import RobotError, Workspace
from .kinematics import check_joints, forward_kinematics
from .rtde import pose_from_transform, transform_from_pose
from .sim import FaultPlan, HOME_JOINTS_RAD, SimulatedUR5e

__all__ = ["Command", "ControllerProcess", "SimulatedController", "main", "DASHBOARD_PORT", "RTDE_PORT", "SCRIPT_PORT"]

DASHBOARD_PORT = 29999
RTDE_PORT = 30004
SCRIPT_PORT = 30003
#: Reported as ``v`` (major, minor, bugfix, build): an e-Series controller.
CONTROLLER_VERSION = (5, 11, 1, 108318)
RTDE_PROTOCOL_VERSION = 2
POLYSCOPE_VERSION_LINE = "URSoftware 5.11.1.108318 (Dec 10 2021)"
SERIAL_NUMBER = "20235500001"

# Runtime states, robot/safety modes and status bits as the RTDE guide numbers them.
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP = 1, 3
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE_STOP = 1 << 0, 1 << 2
ROBOT_BIT_POWER_ON, ROBOT_BIT_PROGRAM_RUNNING = 1 << 0, 1 << 1
JOINT_MODE_RUNNING = 253

# Register handshake values in output int register 0.
REG_IDLE, REG_READY, REG_DONE = 0, 1, 2

# Streaming period when nothing changes; every state change is pushed at once besides. The client
# closes its socket after 2.5 s without data.
STREAM_PERIOD_S = 0.02


class Command:
    """Command numbers written by ur-rtde 1.6.5 to input int register 0 (observed)."""

    MOVEJ = 1
    MOVEJ_IK = 2
    MOVEL = 3
    MOVEL_FK = 4
    SET_TCP = 29
    GET_INVERSE_KIN_NEAR = 30
    PROTECTIVE_STOP = 31
    STOPL = 33
    STOPJ = 34
    IS_POSE_WITHIN_SAFETY_LIMITS = 36
    IS_JOINTS_WITHIN_SAFETY_LIMITS = 37
    GET_TCP_OFFSET = 40
    GET_FORWARD_KIN = 43
    GET_FORWARD_KIN_JOINTS = 44
    GET_INVERSE_KIN = 46
    IS_STEADY = 47
    GET_ACTUAL_TOOL_FLANGE_POSE = 58
    HAS_INVERSE_KIN = 60
    HAS_INVERSE_KIN_NEAR = 61
    STOP_SCRIPT = 255


_TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}


def _field_types() -> dict[str, str]:
    table: dict[str, str] = {}

    def put(names: str, typ: str) -> None:
        for n in names.split():
            table[n] = typ

    put(
        "timestamp actual_execution_time speed_scaling target_speed_fraction actual_momentum "
        "actual_main_voltage actual_robot_voltage actual_robot_current standard_analog_input0 "
        "standard_analog_input1 standard_analog_output0 standard_analog_output1 io_current "
        "tool_analog_input0 tool_analog_input1 tool_output_current tool_temperature tcp_force_scalar "
        "payload speed_slider_fraction joint_position_deviation_ratio collision_detection_ratio",
        "DOUBLE",
    )
    put(
        "target_q target_qd target_qdd target_current target_moment actual_q actual_qd actual_current "
        "joint_control_output actual_TCP_pose actual_TCP_speed actual_TCP_force target_TCP_pose "
        "target_TCP_speed joint_temperatures actual_joint_voltage payload_inertia ft_raw_wrench "
        "external_force_torque",
        "VECTOR6D",
    )
    put("actual_digital_input_bits actual_digital_output_bits", "UINT64")
    put("robot_mode safety_mode safety_status tool_output_voltage", "INT32")
    put("joint_mode", "VECTOR6INT32")
    put("actual_tool_accelerometer payload_cog elbow_position elbow_velocity", "VECTOR3D")
    put(
        "runtime_state robot_status_bits safety_status_bits analog_io_types tool_mode "
        "tool_analog_input_types output_bit_registers0_to_31 output_bit_registers32_to_63 "
        "speed_slider_mask script_control_line input_bit_registers0_to_31 input_bit_registers32_to_63",
        "UINT32",
    )
    put(
        "standard_digital_output_mask standard_digital_output configurable_digital_output_mask "
        "configurable_digital_output tool_digital_output_mask tool_digital_output "
        "standard_analog_output_mask standard_analog_output_type",
        "UINT8",
    )
    return table


FIELD_TYPES = _field_types()
N_REGISTERS = 48


def field_type(name: str) -> str:
    """RTDE type name of an output/input field, or ``NOT_FOUND`` (which makes the client raise)."""
    if name in FIELD_TYPES:
        return FIELD_TYPES[name]
    for prefix, typ in (
        ("input_int_register_", "INT32"),
        ("output_int_register_", "INT32"),
        ("input_double_register_", "DOUBLE"),
        ("output_double_register_", "DOUBLE"),
        ("input_bit_register_", "BOOL"),
        ("output_bit_register_", "BOOL"),
    ):
        if name.startswith(prefix) and name[len(prefix) :].isdigit() and int(name[len(prefix) :]) < 128:
            return typ
    return "NOT_FOUND"


class _Recipe:
    """A recipe: field names and the struct that packs/unpacks their values (after the id byte)."""

    def __init__(self, recipe_id: int, names: list[str]):
        self.id = recipe_id
        self.names = names
        self.types = [field_type(n) for n in names]
        self.valid = "NOT_FOUND" not in self.types
        self.struct = struct.Struct(">B" + "".join(_TYPE_FORMATS[t] for t in self.types)) if self.valid else None

    def pack(self, values: dict) -> bytes:
        flat: list = [self.id]
        for name, typ in zip(self.names, self.types):
            v = values.get(name, 0)
            if typ.startswith("VECTOR"):
                flat.extend(v if not np.isscalar(v) else [v] * (6 if "6" in typ else 3))
            else:
                flat.append(v)
        return self.struct.pack(*flat)

    def unpack(self, payload: bytes) -> dict:
        vals = self.struct.unpack(payload)
        return dict(zip(self.names, vals[1:]))


def _frame(ptype: str, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", 3 + len(payload), ord(ptype)) + payload


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        buf += chunk
    return bytes(buf)


class _Motion:
    """A move in progress: its plan, wall start time, and a stop request."""

    def __init__(self, plan, time_scale: float):
        self.plan = plan
        self.t0 = time.monotonic()
        self.time_scale = time_scale
        self.stop = threading.Event()
        self.ended = threading.Event()

    def elapsed_sim_s(self) -> float:
        if self.time_scale <= 0:
            return math.inf
        return (time.monotonic() - self.t0) / self.time_scale


class SimulatedController:
    """The controller's state and servers; see the module docstring. Call :meth:`serve_forever`."""

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
        self.sim = sim
        self.faults = faults if faults is not None else FaultPlan()
        self.time_scale = float(time_scale)
        self.verbose = verbose
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.runtime_state = RUNTIME_STOPPED
        self.out_int = [0] * N_REGISTERS
        self.out_double = [0.0] * N_REGISTERS
        self.in_int = [0] * N_REGISTERS
        self.in_double = [0.0] * N_REGISTERS
        self.busy = False
        self.prev_cmd = 0
        # Bumped whenever the program starts or stops: a command queued under an older program
        # (e.g. delayed by --command-delay-s while its client went away) is never executed.
        self.generation = 0
        self.motion: _Motion | None = None
        self.drop_on_next_command: str | None = None
        self.commands: queue.Queue = queue.Queue()
        self.t_start = time.monotonic()
        self.shutdown = threading.Event()
        self.clients: set[socket.socket] = set()
        self.listeners: list[socket.socket] = []

    # -- bookkeeping ---------------------------------------------------------------------------
    def log(self, *parts) -> None:
        if self.verbose:
            print(f"[controller {self.host}]", *parts, file=sys.stderr, flush=True)

    def notify(self) -> None:
        with self.changed:
            self.changed.notify_all()

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
        self._stop_motion()
        with self.lock:
            clients = list(self.clients)
            self.clients.clear()
            self.busy = False
        for s in clients:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            try:
                s.close()
            except OSError:
                pass
        self.notify()

    # -- arm state -----------------------------------------------------------------------------
    def current_q(self) -> np.ndarray:
        with self.lock:
            m = self.motion
            if m is None:
                return self.sim.joints()
            return m.plan.joints_at(m.elapsed_sim_s())

    def values(self) -> dict:
        """Every output field's current value (SI units and axis-angle at this boundary)."""
        with self.lock:
            q = self.current_q()
            moving = self.motion is not None
            T_flange_tcp = self.sim.tcp_offset()
            pstop = self.sim.state().protective_stop
            T_tcp = forward_kinematics(q, self.sim.dh) @ T_flange_tcp
            tcp = pose_from_transform(T_tcp)
            speed = [0.0] * 6
            target_tcp = tcp
            target_q = q
            if moving:
                m = self.motion
                t = m.elapsed_sim_s()
                dt = 1e-3
                q2 = m.plan.joints_at(t + dt)
                p2 = (forward_kinematics(q2, self.sim.dh) @ T_flange_tcp)[:3, 3]
                speed[:3] = ((p2 - T_tcp[:3, 3]) / dt / 1000.0).tolist()
                target_tcp = pose_from_transform(m.plan.T_base_tcp_target)
                target_q = m.plan.q_final
            vals = {
                "timestamp": time.monotonic() - self.t_start,
                "actual_q": list(q),
                "target_q": list(target_q),
                "actual_qd": [0.0] * 6,
                "actual_TCP_pose": list(tcp),
                "target_TCP_pose": list(target_tcp),
                "actual_TCP_speed": speed,
                "target_TCP_speed": speed,
                "robot_mode": ROBOT_MODE_RUNNING,
                "joint_mode": [JOINT_MODE_RUNNING] * 6,
                "safety_mode": SAFETY_MODE_PROTECTIVE_STOP if pstop else SAFETY_MODE_NORMAL,
                "safety_status": SAFETY_MODE_PROTECTIVE_STOP if pstop else SAFETY_MODE_NORMAL,
                "safety_status_bits": SAFETY_BIT_PROTECTIVE_STOP if pstop else SAFETY_BIT_NORMAL,
                "robot_status_bits": ROBOT_BIT_POWER_ON
                | (ROBOT_BIT_PROGRAM_RUNNING if self.runtime_state == RUNTIME_PLAYING else 0),
                "runtime_state": self.runtime_state,
                "speed_scaling": 1.0,
                "target_speed_fraction": 1.0,
                "actual_main_voltage": 48.0,
                "actual_robot_voltage": 48.0,
                "joint_temperatures": [30.0] * 6,
                "actual_tool_accelerometer": [0.0, 0.0, -9.81],
            }
            for i in range(N_REGISTERS):
                vals[f"output_int_register_{i}"] = self.out_int[i]
                vals[f"output_double_register_{i}"] = self.out_double[i]
                vals[f"input_int_register_{i}"] = self.in_int[i]
                vals[f"input_double_register_{i}"] = self.in_double[i]
            return vals

    # -- the "program" (register protocol) ------------------------------------------------------
    def start_script(self) -> None:
        self._stop_motion()  # outside the lock: the motion thread needs it to finish
        with self.lock:
            self.runtime_state = RUNTIME_PLAYING
            self.out_int = [0] * N_REGISTERS
            self.out_double = [0.0] * N_REGISTERS
            self.out_int[0] = REG_READY
            self.busy = False
            self.generation += 1
            # Edge-triggered commands: a register value left from before the upload is no command.
            self.prev_cmd = self.in_int[0]
        self.log("control script started")
        self.notify()

    def stop_script(self) -> None:
        self._stop_motion()
        with self.lock:
            self.runtime_state = RUNTIME_STOPPED
            self.out_int[0] = REG_IDLE
            self.busy = False
            self.generation += 1
        self.log("control script stopped")
        self.notify()

    def on_inputs(self, fields: dict) -> None:
        """An input packet from a client: update registers and run the handshake."""
        with self.lock:
            for name, value in fields.items():
                if name.startswith("input_int_register_"):
                    self.in_int[int(name.rsplit("_", 1)[1])] = int(value)
                elif name.startswith("input_double_register_"):
                    self.in_double[int(name.rsplit("_", 1)[1])] = float(value)
            if "input_int_register_0" not in fields:
                return
            cmd = self.in_int[0]
            prev, self.prev_cmd = self.prev_cmd, cmd
            if self.runtime_state != RUNTIME_PLAYING:
                return
            if cmd == 0:
                if self.out_int[0] == REG_DONE:
                    self.out_int[0] = REG_READY
                    self.changed.notify_all()
                return
            if cmd != prev and self.out_int[0] == REG_READY and not self.busy:
                if self.drop_on_next_command is not None:
                    why, self.drop_on_next_command = self.drop_on_next_command, None
                    threading.Thread(target=self.drop_connections, args=(why,), daemon=True).start()
                    return
                self.busy = True
                self.commands.put((self.generation, cmd, list(self.in_int), list(self.in_double)))

    def command_worker(self) -> None:
        while not self.shutdown.is_set():
            try:
                generation, cmd, ints, doubles = self.commands.get(timeout=0.2)
            except queue.Empty:
                continue
            if self.faults.command_delay_s > 0:
                time.sleep(self.faults.command_delay_s)
            with self.lock:
                stale = generation != self.generation or self.runtime_state != RUNTIME_PLAYING
            if stale:
                self.log(f"command {cmd} dropped: its program ended while it waited")
                continue
            try:
                self.execute(cmd, ints, doubles)
            except Exception as exc:  # a crashing command must not kill the controller
                self.log(f"command {cmd} failed: {exc!r}")
            with self.lock:
                if self.busy and self.runtime_state == RUNTIME_PLAYING:
                    self.out_int[0] = REG_DONE
                self.busy = False
            self.notify()

    def _result_pose(self, pose6) -> None:
        with self.lock:
            self.out_double[0:6] = [float(v) for v in pose6]

    def _result_bool(self, flag: bool) -> None:
        with self.lock:
            self.out_int[1] = 1 if flag else 0

    def execute(self, cmd: int, ints: list, doubles: list) -> None:
        """Run one register command (numbers in :class:`Command`)."""
        C = Command
        pose = doubles[0:6]
        self.log("command", cmd, "params", [round(d, 6) for d in doubles[:14]])
        if cmd == C.STOP_SCRIPT:
            self.stop_script()
            return
        if cmd in (C.MOVEL, C.MOVEL_FK, C.MOVEJ, C.MOVEJ_IK):
            self._move(cmd, doubles, asynchronous=bool(ints[1]))
            return
        if cmd in (C.STOPL, C.STOPJ):
            self._stop_motion()
            return
        if cmd == C.PROTECTIVE_STOP:
            self._protective_stop("triggered by the client")
            return
        if cmd == C.SET_TCP:
            T = transform_from_pose(pose, "tcp_offset")
            with self.lock:
                self.sim.set_tcp(T)
            return
        if cmd == C.GET_TCP_OFFSET:
            self._result_pose(pose_from_transform(self.sim.tcp_offset()))
            return
        if cmd == C.GET_FORWARD_KIN:
            self._result_pose(pose_from_transform(self.sim.tcp_pose_for_joints(self.current_q())))
            return
        if cmd == C.GET_FORWARD_KIN_JOINTS:
            # Like the observed client, the explicit-TCP variant reuses this number; the current
            # TCP offset applies (the client's FK with an explicit offset is not to be relied on).
            q = check_joints(doubles[0:6], "q")
            self._result_pose(pose_from_transform(self.sim.tcp_pose_for_joints(q)))
            return
        if cmd == C.GET_ACTUAL_TOOL_FLANGE_POSE:
            self._result_pose(pose_from_transform(forward_kinematics(self.current_q(), self.sim.dh)))
            return
        if cmd == C.IS_STEADY:
            with self.lock:
                self._result_bool(self.motion is None)
            return
        if cmd == C.IS_POSE_WITHIN_SAFETY_LIMITS:
            self._result_bool(self._pose_ok(pose) and self.sim.is_pose_safe(transform_from_pose(pose)))
            return
        if cmd == C.IS_JOINTS_WITHIN_SAFETY_LIMITS:
            try:
                q = check_joints(doubles[0:6], "q")
                self._result_bool(self.sim.is_pose_safe(self.sim.tcp_pose_for_joints(q)))
            except ValueError:
                self._result_bool(False)
            return
        if cmd in (C.HAS_INVERSE_KIN, C.HAS_INVERSE_KIN_NEAR):
            q_near = doubles[6:12] if cmd == C.HAS_INVERSE_KIN_NEAR else None
            ok = self._pose_ok(pose) and self._q_ok(q_near)
            self._result_bool(ok and self.sim.has_inverse_kinematics(transform_from_pose(pose), q_near))
            return
        if cmd in (C.GET_INVERSE_KIN, C.GET_INVERSE_KIN_NEAR):
            q_near = doubles[6:12] if cmd == C.GET_INVERSE_KIN_NEAR else None
            try:
                q = self.sim.inverse_kinematics(transform_from_pose(pose), q_near)
            except (RobotError, ValueError) as exc:
                # On a real controller a failed get_inverse_kin is a runtime error of the program.
                self.log("inverse kinematics failed, stopping the program:", exc)
                self.stop_script()
                return
            self._result_pose(q)
            return
        self.log(f"unknown command {cmd}: ignored")

    @staticmethod
    def _pose_ok(pose) -> bool:
        return len(pose) == 6 and all(math.isfinite(v) for v in pose)

    @staticmethod
    def _q_ok(q) -> bool:
        if q is None:
            return True
        try:
            check_joints(q, "q_near")
        except ValueError:
            return False
        return True

    def _protective_stop(self, why: str) -> None:
        self.log("protective stop:", why)
        self._stop_motion()
        with self.lock:
            self.sim.trigger_protective_stop()
        self.notify()

    def _stop_motion(self) -> None:
        with self.lock:
            m = self.motion
        if m is not None:
            m.stop.set()
            m.ended.wait(timeout=2.0)

    def _move(self, cmd: int, doubles: list, asynchronous: bool) -> None:
        C = Command
        with self.lock:
            if self.sim.state().protective_stop:
                self.log("move refused: protective stop")
                return
        self._stop_motion()  # a new move replaces one still running (asynchronous moves)
        try:
            if cmd in (C.MOVEL, C.MOVEL_FK, C.MOVEJ_IK):
                if cmd == C.MOVEL_FK:
                    target = self.sim.tcp_pose_for_joints(check_joints(doubles[0:6], "q"))
                else:
                    target = transform_from_pose(doubles[0:6], "pose")
                speed_mm_s, acc_mm_s2 = doubles[6] * 1000.0, doubles[7] * 1000.0
                with self.lock:
                    plan = self.sim.plan_linear(target, speed_mm_s, acc_mm_s2)
            else:
                # moveJ: executed as a linear move to the target configuration's pose (module docstring).
                q = check_joints(doubles[0:6], "q")
                target = self.sim.tcp_pose_for_joints(q)
                with self.lock:
                    plan = self.sim.plan_linear(target, 250.0, 1200.0)
        except (RobotError, ValueError) as exc:
            # The controller protects the arm: a move it cannot make ends in a protective stop.
            self._protective_stop(f"move rejected: {exc}")
            return
        motion = _Motion(plan, self.time_scale)
        with self.lock:
            self.motion = motion
        self.notify()
        if asynchronous:
            threading.Thread(target=self._run_motion, args=(motion,), daemon=True).start()
        else:
            self._run_motion(motion)

    def _run_motion(self, motion: _Motion) -> None:
        plan = motion.plan
        k = self.sim.moves_planned
        f = self.faults
        interrupt_at = None
        if f.disconnect_during_move == k or f.protective_stop_during_move == k:
            interrupt_at = 0.5 * plan.duration_s
        try:
            while True:
                t = motion.elapsed_sim_s()
                if interrupt_at is not None and t >= interrupt_at:
                    with self.lock:
                        self.sim.finish(plan, interrupt_at)
                        self.motion = None
                    if f.protective_stop_during_move == k:
                        with self.lock:
                            self.sim.trigger_protective_stop()
                        self.log(f"injected protective stop during move {k}")
                        self.notify()
                    else:
                        motion.ended.set()
                        self.drop_connections(f"injected disconnect during move {k}")
                    return
                if t >= plan.duration_s:
                    with self.lock:
                        self.sim.finish(plan)
                        self.motion = None
                    self.notify()
                    if f.disconnect_after_moves == k:
                        # The link drops after the move has been reported done: at the next command.
                        with self.lock:
                            self.drop_on_next_command = f"injected disconnect after move {k}"
                    return
                if motion.stop.is_set() or self.shutdown.is_set():
                    with self.lock:
                        self.sim.finish(plan, t)
                        self.motion = None
                    self.notify()
                    return
                remaining = (min(plan.duration_s, interrupt_at or math.inf) - t) * self.time_scale
                motion.stop.wait(timeout=max(0.0, min(STREAM_PERIOD_S, remaining)))
                self.notify()  # stream the intermediate pose
        finally:
            motion.ended.set()

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
                except socket.timeout:
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
            playing = self.runtime_state == RUNTIME_PLAYING
        if cmd == "polyscopeversion":
            return POLYSCOPE_VERSION_LINE
        if cmd == "get serial number":
            return SERIAL_NUMBER
        if cmd == "is in remote control":
            return "true"
        if cmd == "unlock protective stop":
            with self.lock:
                self.sim.clear_protective_stop()
            self.notify()
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
            self.stop_script()
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
            except socket.timeout:
                chunk = None
            if chunk:
                data += chunk
                continue
            if data:
                self.log(f"script received ({len(data)} bytes)")
                if b"def rtde_control" in data:
                    self.start_script()
                data = b""
            if chunk == b"":
                return
            conn.settimeout(None)

    def _rtde(self, conn: socket.socket) -> None:
        send_lock = threading.Lock()
        outputs: list[_Recipe] = []
        inputs: dict[int, _Recipe] = {}
        streaming = threading.Event()

        def send(ptype: str, payload: bytes = b"") -> None:
            with send_lock:
                conn.sendall(_frame(ptype, payload))

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
                self.stop_script()

    def _rtde_loop(self, conn, send, outputs, inputs, streaming, stream) -> None:
        while not self.shutdown.is_set():
            size, ptype = struct.unpack(">HB", _recv_exact(conn, 3))
            payload = _recv_exact(conn, size - 3) if size > 3 else b""
            t = chr(ptype)
            if t == "U":
                recipe = inputs.get(payload[0])
                if recipe is None:
                    self.log(f"input packet for unknown recipe {payload[0]}")
                    continue
                self.on_inputs(recipe.unpack(payload))
            elif t == "V":
                (version,) = struct.unpack(">H", payload[:2])
                send("V", bytes([1 if version == RTDE_PROTOCOL_VERSION else 0]))
            elif t == "v":
                send("v", struct.pack(">IIII", *CONTROLLER_VERSION))
            elif t == "O":
                (freq,) = struct.unpack(">d", payload[:8])
                names = [n for n in payload[8:].decode().split(",") if n]
                recipe = _Recipe(len(outputs) + 1, names)
                self.log(f"output recipe {recipe.id} at {freq:g} Hz: {len(names)} fields")
                if recipe.valid:
                    outputs.append(recipe)
                    send("O", bytes([recipe.id]) + ",".join(recipe.types).encode())
                else:
                    send("O", bytes([0]) + ",".join(recipe.types).encode())
            elif t == "I":
                names = [n for n in payload.decode().split(",") if n]
                recipe = _Recipe(len(inputs) + 1, names)
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
        threading.Thread(target=self.command_worker, daemon=True).start()

    def close(self) -> None:
        self.shutdown.set()
        self.drop_connections("controller shutting down")
        for s in self.listeners:
            try:
                s.close()
            except OSError:
                pass

    def serve_forever(self, max_lifetime_s: float, parent_pid: int | None = None) -> None:
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
    p.add_argument("--command-delay-s", type=float, default=0.0, help="answer every command this late (slow controller)")
    p.add_argument("--max-lifetime-s", type=float, default=3600.0, help="exit after this many seconds")
    p.add_argument("--parent-pid", type=int, default=None, help="exit when this process is gone")
    p.add_argument("--verbose", action="store_true")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
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
    print(f"simulated UR controller ready on {args.host} (ports {DASHBOARD_PORT}, {RTDE_PORT}, {SCRIPT_PORT})", flush=True)
    try:
        ctrl.serve_forever(args.max_lifetime_s, args.parent_pid)
    except KeyboardInterrupt:
        ctrl.close()
    return 0


class ControllerProcess:
    """The simulated controller in a child process (for tests, benchmarks and notebooks).

    ``ControllerProcess("127.0.0.2", "--repeatability-mm", "0")`` starts
    ``python -m histostudy.robot.controller --host 127.0.0.2 ...`` and waits (at most
    ``start_timeout_s``) until its three ports accept connections. Use as a context manager or
    call :meth:`stop`; :meth:`kill` simulates a crashed controller (SIGKILL).
    """

    def __init__(self, host: str, *args: str, start_timeout_s: float = 20.0, max_lifetime_s: float = 600.0):
        if not ipaddress.ip_address(host).is_loopback:
            raise ValueError(f"host must be a loopback address (127.0.0.0/8), got {host!r}")
        self.host = host
        cmd = [
            sys.executable, "-m", "histostudy.robot.controller", "--host", host,
            "--max-lifetime-s", str(max_lifetime_s), "--parent-pid", str(os.getpid()), *map(str, args),
        ]
        # A file, not a pipe, for the log: a full pipe would block the controller.
        self.log = tempfile.TemporaryFile(mode="w+t")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + start_timeout_s
        pending = [DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT]
        while pending:
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"simulated controller on {host} exited with status {self.proc.returncode}: {self.output().strip()}"
                )
            if time.monotonic() > deadline:
                self.kill()
                raise TimeoutError(f"simulated controller on {host} did not open ports {pending} within {start_timeout_s} s")
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


if __name__ == "__main__":
    sys.exit(main())
