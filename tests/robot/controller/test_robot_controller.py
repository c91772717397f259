"""The simulated UR controller's protocols, spoken from raw sockets (no ur_rtde), in process.

These pin the wire facts ur-rtde 1.6.5 relies on (see histostudy/robot/controller/_protocol.py and
_program.py); the end-to-end path through the real client is in tests/robot/rtde/test_robot_rtde.py.
"""

import os
import re
import signal
import socket
import struct
import time

import numpy as np
import pytest

from histostudy.robot import (
    HOME_JOINTS_RAD,
    SimulatedUR5e,
    forward_kinematics,
    pose_from_transform,
    transform_from_pose,
)
from histostudy.robot.controller._process import Command, SimulatedController, main

_BLOCK = 20 + (os.getpid() + 101) % 200
_next = iter(range(1, 250))


@pytest.fixture(autouse=True)
def time_limit():
    def on_alarm(signum, frame):
        raise TimeoutError("test exceeded 20 s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def ctrl():
    host = f"127.{_BLOCK}.{next(_next)}.2"
    c = SimulatedController(host, SimulatedUR5e(0, repeatability_mm=0.0))
    c.start()
    yield c
    c.close()


class RawRTDE:
    """A minimal RTDE client for the tests: frames of >HB (size incl. header, type)."""

    def __init__(self, host):
        self.sock = socket.create_connection((host, 30004), timeout=2.0)

    def send(self, ptype, payload=b""):
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), ord(ptype)) + payload)

    def recv(self):
        head = self._exact(3)
        size, ptype = struct.unpack(">HB", head)
        return chr(ptype), self._exact(size - 3)

    def recv_type(self, ptype):
        for _ in range(1000):
            t, payload = self.recv()
            if t == ptype:
                return payload
        raise AssertionError(f"no {ptype!r} packet")

    def _exact(self, n):
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            assert chunk, "connection closed"
            buf += chunk
        return buf

    def setup_outputs(self, names, freq=125.0):
        self.send("O", struct.pack(">d", freq) + ",".join(names).encode())
        payload = self.recv_type("O")
        return payload[0], payload[1:].decode().split(",")

    def setup_inputs(self, names):
        self.send("I", ",".join(names).encode())
        payload = self.recv_type("I")
        return payload[0], payload[1:].decode().split(",")

    def close(self):
        self.sock.close()


FMT = {"DOUBLE": "d", "VECTOR6D": "6d", "UINT32": "I", "INT32": "i", "UINT64": "Q", "VECTOR6INT32": "6i",
       "VECTOR3D": "3d"}


def decode(types, payload):
    fmt = ">B" + "".join(FMT[t] for t in types)
    return struct.unpack(fmt, payload)


def test_serves_loopback_only():
    with pytest.raises(ValueError, match="loopback"):
        SimulatedController("10.1.2.3", SimulatedUR5e(0))
    assert main(["--host", "192.0.2.1", "--max-lifetime-s", "1"]) == 2


def test_handshake_version_and_recipe_types(ctrl):
    c = RawRTDE(ctrl.host)
    c.send("V", struct.pack(">H", 2))
    assert c.recv() == ("V", b"\x01")
    c.send("V", struct.pack(">H", 3))
    assert c.recv() == ("V", b"\x00")
    c.send("v")
    t, payload = c.recv()
    assert t == "v" and struct.unpack(">IIII", payload) == (5, 11, 1, 108318)
    names = [
        "timestamp", "actual_q", "actual_TCP_pose", "actual_digital_input_bits", "runtime_state",
        "robot_status_bits", "safety_status_bits", "robot_mode", "safety_mode", "joint_mode",
        "actual_tool_accelerometer", "payload_cog", "output_int_register_0", "output_double_register_5",
    ]
    rid, types = c.setup_outputs(names)
    assert rid == 1
    assert types == [
        "DOUBLE", "VECTOR6D", "VECTOR6D", "UINT64", "UINT32", "UINT32", "UINT32", "INT32", "INT32",
        "VECTOR6INT32", "VECTOR3D", "VECTOR3D", "INT32", "DOUBLE",
    ]
    rid_bad, types_bad = c.setup_outputs(["timestamp", "no_such_field"])
    assert types_bad == ["DOUBLE", "NOT_FOUND"]  # makes the client raise, as a real controller does
    # Input recipes get ids 1..N in the order requested (the client hard-codes them).
    ids = [c.setup_inputs(["input_int_register_0"] + [f"input_double_register_{i}" for i in range(k)])[0]
           for k in range(4)]
    assert ids == [1, 2, 3, 4]
    c.send("S")
    assert c.recv_type("S") == b"\x01"
    values = decode(types, c.recv_type("U"))
    assert values[0] == 1
    assert np.allclose(values[2:8], HOME_JOINTS_RAD)
    expected_tcp = pose_from_transform(forward_kinematics(HOME_JOINTS_RAD))
    assert np.allclose(values[8:14], expected_tcp, atol=1e-12)
    c.close()


def test_streams_while_idle_faster_than_the_clients_timeout(ctrl):
    c = RawRTDE(ctrl.host)
    _, types = c.setup_outputs(["timestamp"])
    c.send("S")
    c.recv_type("S")
    stamps = [decode(types, c.recv_type("U"))[1] for _ in range(6)]
    assert np.all(np.diff(stamps) > 0)
    assert np.diff(stamps).max() < 0.5  # the client gives up after 2.5 s without data
    c.close()


def _upload_script(host):
    with socket.create_connection((host, 30003), timeout=2.0) as s:
        s.sendall(b"def rtde_control():\n  textmsg(\"test\")\nend\n")
        time.sleep(0.2)


def test_register_protocol_ready_command_done(ctrl):
    c = RawRTDE(ctrl.host)
    _, out_types = c.setup_outputs(["runtime_state", "output_int_register_0", "output_int_register_1"]
                                   + [f"output_double_register_{i}" for i in range(6)])
    in_names = ["input_int_register_0"] + [f"input_double_register_{i}" for i in range(8)]
    rid, _ = c.setup_inputs(in_names)
    c.send("S")
    c.recv_type("S")
    assert decode(out_types, c.recv_type("U"))[1] == 1  # no program running yet
    _upload_script(ctrl.host)

    def wait_for(pred):
        for _ in range(500):
            v = decode(out_types, c.recv_type("U"))
            if pred(v):
                return v
        raise AssertionError("condition not reached")

    wait_for(lambda v: v[1] == 2 and v[2] == 1)  # program running, "ready"

    def command(cmd, doubles, speed_acc=(0.25, 1.2)):
        c.send("U", struct.pack(">Bi8d", rid, cmd, *doubles, *speed_acc))
        v = wait_for(lambda v: v[2] == 2)  # "done"
        c.send("U", struct.pack(">Bi8d", rid, 0, *[0.0] * 8))
        wait_for(lambda v: v[2] == 1)  # back to "ready"
        return v

    tcp = [0.01, -0.02, 0.15, 0.0, 0.0, 0.3]
    command(Command.SET_TCP, tcp)
    assert np.allclose(ctrl.sim.tcp_offset(), transform_from_pose(tcp))
    v = command(Command.GET_FORWARD_KIN, [0.0] * 6)
    expected = forward_kinematics(HOME_JOINTS_RAD) @ transform_from_pose(tcp)
    assert np.allclose(transform_from_pose(v[4:10]), expected, atol=1e-9)
    target = expected.copy()
    target[:3, 3] += [30.0, 0.0, 0.0]
    v = command(Command.IS_POSE_WITHIN_SAFETY_LIMITS, pose_from_transform(target))
    assert v[3] == 1
    far = target.copy()
    far[:3, 3] = [-1500.0, 0.0, 0.0]
    assert command(Command.IS_POSE_WITHIN_SAFETY_LIMITS, pose_from_transform(far))[3] == 0
    assert command(Command.HAS_INVERSE_KIN, pose_from_transform(far))[3] == 0
    v = command(Command.GET_INVERSE_KIN, pose_from_transform(target))
    assert np.allclose(forward_kinematics(v[4:10]) @ transform_from_pose(tcp), target, atol=1e-9)
    # A move with valid parameters moves the arm ...
    command(Command.MOVEL, pose_from_transform(target))
    assert np.allclose(ctrl.sim.tcp_pose(), target, atol=1e-9)
    command(Command.PROTECTIVE_STOP, [0.0] * 6)
    assert ctrl.sim.state().protective_stop
    target = target.copy()
    target[:3, 3] += [0.0, 20.0, 0.0]
    # ... under the protective stop it is acknowledged but the arm does not move.
    q_before = ctrl.sim.joints()
    command(Command.MOVEL, pose_from_transform(target))
    assert np.array_equal(ctrl.sim.joints(), q_before)
    # STOP_SCRIPT ends the program: runtime_state back to stopped, register 0 idle.
    c.send("U", struct.pack(">Bi8d", rid, Command.STOP_SCRIPT, *[0.0] * 8))
    wait_for(lambda v: v[1] == 1 and v[2] == 0)
    c.close()


def test_dashboard_replies_what_the_client_parses(ctrl):
    with socket.create_connection((ctrl.host, 29999), timeout=2.0) as s:
        f = s.makefile("rwb")
        assert f.readline().startswith(b"Connected: Universal Robots Dashboard Server")

        def ask(line):
            f.write(line.encode() + b"\n")
            f.flush()
            return f.readline().decode().strip()

        assert re.search(r"\d+\.\d+\.\d+\.\d+", ask("PolyscopeVersion"))
        assert ask("get serial number").isdigit()
        assert ask("is in remote control") == "true"
        ctrl.sim.trigger_protective_stop()
        assert ask("safetystatus") == "Safetystatus: PROTECTIVE_STOP"
        assert ask("unlock protective stop") == "Protective stop releasing"
        assert not ctrl.sim.state().protective_stop
        assert "could not understand" in ask("fly")
