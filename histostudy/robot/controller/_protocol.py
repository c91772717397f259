"""The UR controller's wire protocols as ur_rtde uses them (§II-C): ports, versions, status codes, the
register command numbers, RTDE field types, recipes and packet framing; no arm and no sockets."""

from __future__ import annotations

import socket
import struct

import numpy as np

__all__ = ["Command", "DASHBOARD_PORT", "RTDE_PORT", "RTDERecipe", "SCRIPT_PORT", "field_type"]

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


class RTDERecipe:
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
        return self._checked_struct().pack(*flat)

    def unpack(self, payload: bytes) -> dict:
        vals = self._checked_struct().unpack(payload)
        return dict(zip(self.names, vals[1:]))

    def _checked_struct(self) -> struct.Struct:
        """The recipe's binary layout; ``ValueError`` for a recipe that names a variable the
        controller does not know (it has none)."""
        if self.struct is None:
            raise ValueError(f"recipe {self.id} names variables the controller does not know: it has no layout")
        return self.struct


def rtde_packet(ptype: str, payload: bytes = b"") -> bytes:
    """One RTDE packet: big-endian uint16 size (header included), uint8 type, payload."""
    return struct.pack(">HB", 3 + len(payload), ord(ptype)) + payload


def recv_exact(sock: socket.socket, n: int) -> bytes:
    """Exactly ``n`` bytes from ``sock``; ConnectionError if the peer closes first."""
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed the connection")
        buf += chunk
    return bytes(buf)
