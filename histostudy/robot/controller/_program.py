"""The control program on the simulated UR controller (§II-C): the register handshake through which ur_rtde
sends its commands, and what each command does (SI units and axis-angle on the wire)."""

from __future__ import annotations

import math
import queue
import threading
import time

from ..base import RobotError
from ..kinematics import check_joints, forward_kinematics
from ..units import pose_from_transform, transform_from_pose
from ._arm import ControllerArm
from ._protocol import (
    N_REGISTERS,
    REG_DONE,
    REG_IDLE,
    REG_READY,
    ROBOT_BIT_POWER_ON,
    ROBOT_BIT_PROGRAM_RUNNING,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    Command,
)

__all__ = ["ControlProgram"]


class ControlProgram:
    """The program's state (runtime state, registers, the command queue) over a :class:`ControllerArm`.

    ``on_disconnect(why)`` drops every client connection (the arm's injected faults and the one
    due at the next command). Call :meth:`command_worker` on a thread of its own.
    """

    def __init__(self, arm: ControllerArm, *, shutdown: threading.Event, log, on_disconnect):
        self.arm = arm
        self.lock = arm.lock
        self.changed = arm.changed
        self.shutdown = shutdown
        self.log = log
        self.on_disconnect = on_disconnect
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
        self.commands: queue.Queue = queue.Queue()

    def values(self) -> dict:
        """Every output field's current value (SI units and axis-angle at this boundary)."""
        with self.lock:
            vals = self.arm.values()
            vals["robot_status_bits"] = ROBOT_BIT_POWER_ON | (
                ROBOT_BIT_PROGRAM_RUNNING if self.runtime_state == RUNTIME_PLAYING else 0
            )
            vals["runtime_state"] = self.runtime_state
            for i in range(N_REGISTERS):
                vals[f"output_int_register_{i}"] = self.out_int[i]
                vals[f"output_double_register_{i}"] = self.out_double[i]
                vals[f"input_int_register_{i}"] = self.in_int[i]
                vals[f"input_double_register_{i}"] = self.in_double[i]
            return vals

    def start_script(self) -> None:
        self.arm.stop_motion()  # outside the lock: the motion thread needs it to finish
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
        self.arm.notify()

    def stop_script(self) -> None:
        self.arm.stop_motion()
        with self.lock:
            self.runtime_state = RUNTIME_STOPPED
            self.out_int[0] = REG_IDLE
            self.busy = False
            self.generation += 1
        self.log("control script stopped")
        self.arm.notify()

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
                if self.arm.drop_on_next_command is not None:
                    why, self.arm.drop_on_next_command = self.arm.drop_on_next_command, None
                    threading.Thread(target=self.on_disconnect, args=(why,), daemon=True).start()
                    return
                self.busy = True
                self.commands.put((self.generation, cmd, list(self.in_int), list(self.in_double)))

    def command_worker(self) -> None:
        while not self.shutdown.is_set():
            try:
                generation, cmd, ints, doubles = self.commands.get(timeout=0.2)
            except queue.Empty:
                continue
            if self.arm.faults.command_delay_s > 0:
                time.sleep(self.arm.faults.command_delay_s)
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
            self.arm.notify()

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
            self.arm.move(cmd, doubles, asynchronous=bool(ints[1]))
            return
        if cmd in (C.STOPL, C.STOPJ):
            self.arm.stop_motion()
            return
        if cmd == C.PROTECTIVE_STOP:
            self.arm.protective_stop("triggered by the client")
            return
        if cmd == C.SET_TCP:
            T = transform_from_pose(pose, "tcp_offset")
            with self.lock:
                self.arm.sim.set_tcp(T)
            return
        if cmd == C.GET_TCP_OFFSET:
            self._result_pose(pose_from_transform(self.arm.sim.tcp_offset()))
            return
        if cmd == C.GET_FORWARD_KIN:
            self._result_pose(pose_from_transform(self.arm.sim.tcp_pose_for_joints(self.arm.current_q())))
            return
        if cmd == C.GET_FORWARD_KIN_JOINTS:
            # Like the observed client, the explicit-TCP variant reuses this number; the current
            # TCP offset applies (the client's FK with an explicit offset is not to be relied on).
            q = check_joints(doubles[0:6], "q")
            self._result_pose(pose_from_transform(self.arm.sim.tcp_pose_for_joints(q)))
            return
        if cmd == C.GET_ACTUAL_TOOL_FLANGE_POSE:
            self._result_pose(pose_from_transform(forward_kinematics(self.arm.current_q(), self.arm.sim.dh)))
            return
        if cmd == C.IS_STEADY:
            with self.lock:
                self._result_bool(self.arm.motion is None)
            return
        if cmd == C.IS_POSE_WITHIN_SAFETY_LIMITS:
            self._result_bool(self._pose_ok(pose) and self.arm.sim.is_pose_safe(transform_from_pose(pose)))
            return
        if cmd == C.IS_JOINTS_WITHIN_SAFETY_LIMITS:
            try:
                q = check_joints(doubles[0:6], "q")
                self._result_bool(self.arm.sim.is_pose_safe(self.arm.sim.tcp_pose_for_joints(q)))
            except ValueError:
                self._result_bool(False)
            return
        if cmd in (C.HAS_INVERSE_KIN, C.HAS_INVERSE_KIN_NEAR):
            q_near = doubles[6:12] if cmd == C.HAS_INVERSE_KIN_NEAR else None
            ok = self._pose_ok(pose) and self._q_ok(q_near)
            self._result_bool(ok and self.arm.sim.has_inverse_kinematics(transform_from_pose(pose), q_near))
            return
        if cmd in (C.GET_INVERSE_KIN, C.GET_INVERSE_KIN_NEAR):
            q_near = doubles[6:12] if cmd == C.GET_INVERSE_KIN_NEAR else None
            try:
                q = self.arm.sim.inverse_kinematics(transform_from_pose(pose), q_near)
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
