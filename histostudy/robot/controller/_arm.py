"""The arm behind the simulated UR controller (§II-C): a :class:`SimulatedUR5e` whose moves take wall-clock
time, can be stopped, and fail as the :class:`FaultPlan` says; mm inside, metres and axis-angle at its
outputs (:mod:`histostudy.robot.units`)."""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from ..base import RobotError
from ..kinematics import check_joints, forward_kinematics
from ..sim import FaultPlan, SimulatedUR5e
from ..units import pose_from_transform, transform_from_pose
from ._protocol import (
    JOINT_MODE_RUNNING,
    ROBOT_MODE_RUNNING,
    SAFETY_BIT_NORMAL,
    SAFETY_BIT_PROTECTIVE_STOP,
    SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
    STREAM_PERIOD_S,
    Command,
)

__all__ = ["ControllerArm", "MotionInProgress"]


class MotionInProgress:
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


class ControllerArm:
    """The simulated arm, its move in progress and the faults to inject; see the module docstring.

    ``time_scale``: wall seconds per simulated second of motion (0: moves end at once).
    ``lock`` guards the arm and every other part of the controller's state (the program's
    registers too), and ``changed`` is notified on every change, for the RTDE stream.
    ``on_disconnect(why)`` drops every client connection (an injected network fault).
    """

    def __init__(
        self,
        sim: SimulatedUR5e,
        faults: FaultPlan,
        time_scale: float,
        *,
        shutdown: threading.Event,
        log,
        on_disconnect,
    ):
        self.sim = sim
        self.faults = faults
        self.time_scale = float(time_scale)
        self.shutdown = shutdown
        self.log = log
        self.on_disconnect = on_disconnect
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.motion: MotionInProgress | None = None
        # Set after move K of --disconnect-after-moves K; the program drops the link at the next command.
        self.drop_on_next_command: str | None = None
        self.t_start = time.monotonic()

    def notify(self) -> None:
        with self.changed:
            self.changed.notify_all()

    # -- state ---------------------------------------------------------------------------------
    def current_q(self) -> np.ndarray:
        with self.lock:
            m = self.motion
            if m is None:
                return self.sim.joints()
            return m.plan.joints_at(m.elapsed_sim_s())

    def values(self) -> dict:
        """The arm's output fields: time, joints, TCP pose and speed, modes (SI units, axis-angle)."""
        with self.lock:
            q = self.current_q()
            T_flange_tcp = self.sim.tcp_offset()
            pstop = self.sim.state().protective_stop
            T_tcp = forward_kinematics(q, self.sim.dh) @ T_flange_tcp
            tcp = pose_from_transform(T_tcp)
            speed = [0.0] * 6
            target_tcp = tcp
            target_q = q
            m = self.motion
            if m is not None:
                t = m.elapsed_sim_s()
                dt = 1e-3
                q2 = m.plan.joints_at(t + dt)
                p2 = (forward_kinematics(q2, self.sim.dh) @ T_flange_tcp)[:3, 3]
                speed[:3] = ((p2 - T_tcp[:3, 3]) / dt / 1000.0).tolist()
                target_tcp = pose_from_transform(m.plan.T_base_tcp_target)
                target_q = m.plan.q_final
            return {
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
                "speed_scaling": 1.0,
                "target_speed_fraction": 1.0,
                "actual_main_voltage": 48.0,
                "actual_robot_voltage": 48.0,
                "joint_temperatures": [30.0] * 6,
                "actual_tool_accelerometer": [0.0, 0.0, -9.81],
            }

    # -- stops ---------------------------------------------------------------------------------
    def protective_stop(self, why: str) -> None:
        self.log("protective stop:", why)
        self.stop_motion()
        with self.lock:
            self.sim.trigger_protective_stop()
        self.notify()

    def clear_protective_stop(self) -> None:
        with self.lock:
            self.sim.clear_protective_stop()
        self.notify()

    def stop_motion(self) -> None:
        """Stop the move in progress, if any, and wait (bounded) until it has ended."""
        with self.lock:
            m = self.motion
        if m is not None:
            m.stop.set()
            m.ended.wait(timeout=2.0)

    # -- moves ---------------------------------------------------------------------------------
    def move(self, cmd: int, doubles: list, asynchronous: bool) -> None:
        """Run a move command (``Command.MOVEL`` … with the client's double registers: the target pose
        or joints, then speed m/s and acceleration m/s²); returns when it has ended, or at once if
        ``asynchronous``."""
        C = Command
        with self.lock:
            if self.sim.state().protective_stop:
                self.log("move refused: protective stop")
                return
        self.stop_motion()  # a new move replaces one still running (asynchronous moves)
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
            self.protective_stop(f"move rejected: {exc}")
            return
        motion = MotionInProgress(plan, self.time_scale)
        with self.lock:
            self.motion = motion
        self.notify()
        if asynchronous:
            threading.Thread(target=self._run_motion, args=(motion,), daemon=True).start()
        else:
            self._run_motion(motion)

    def _run_motion(self, motion: MotionInProgress) -> None:
        """Let ``motion`` run its course in wall-clock time, streaming, stopping or failing on the way."""
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
                        self.on_disconnect(f"injected disconnect during move {k}")
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
