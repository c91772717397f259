"""SimulatedUR5e: landing within repeatability, determinism, checks before moving, injected faults."""

import math

import numpy as np
import pytest

from histostudy.geometry import invert_transform, make_transform, matrix_from_rotvec
from histostudy.robot import (
    ProtectiveStopError,
    Robot,
    RobotConnectionError,
    RobotTimeout,
    SimulatedUR5e,
    UnreachablePoseError,
    Workspace,
    WorkspaceViolation,
    forward_kinematics,
)
from histostudy.robot.base import trapezoid_time_s
from histostudy.robot.sim import FaultPlan

T_FLANGE_TCP = make_transform(matrix_from_rotvec([0.0, 0.0, 0.4]), [5.0, -3.0, 120.0])


def random_targets(robot, rng, n, step_mm=40.0, tilt_rad=0.15):
    """Poses near the current TCP pose (a random walk the arm can follow)."""
    T = robot.tcp_pose()
    out = []
    for _ in range(n):
        T = make_transform(T[:3, :3] @ matrix_from_rotvec(rng.uniform(-tilt_rad, tilt_rad, 3)),
                           T[:3, 3] + rng.uniform(-step_mm, step_mm, 3))
        out.append(T)
    return out


def test_is_a_robot():
    assert isinstance(SimulatedUR5e(0), Robot)


def test_moves_land_within_repeatability_and_aim_the_tcp():
    robot = SimulatedUR5e(np.random.default_rng(1), repeatability_mm=0.03, T_flange_tcp=T_FLANGE_TCP)
    errors = []
    for T in random_targets(robot, np.random.default_rng(2), 25):
        reached = robot.move_linear(T, speed_mm_s=200, acceleration_mm_s2=1000)
        errors.append(np.linalg.norm(reached[:3, 3] - T[:3, 3]))
        assert np.allclose(reached, robot.tcp_pose())
        # The TCP, not the flange, is what lands on the target; joints and FK agree.
        assert np.allclose(robot.flange_pose() @ T_FLANGE_TCP, reached, atol=1e-9)
        assert np.allclose(forward_kinematics(robot.joints()), robot.flange_pose())
        assert np.allclose(reached[:3, :3], T[:3, :3], atol=1e-3)
    errors = np.array(errors)
    assert errors.max() <= 0.03 + 1e-9
    assert errors.min() > 0 and errors.mean() > 0.005  # the noise is really there


def test_zero_repeatability_is_exact():
    robot = SimulatedUR5e(3, repeatability_mm=0.0, T_flange_tcp=T_FLANGE_TCP)
    for T in random_targets(robot, np.random.default_rng(4), 10):
        assert np.abs(robot.move_linear(T) - T).max() < 1e-9


def test_same_seed_same_poses_other_seed_other_poses():
    def run(seed):
        robot = SimulatedUR5e(seed, repeatability_mm=0.03)
        return [robot.move_linear(T) for T in random_targets(SimulatedUR5e(0), np.random.default_rng(5), 6)]

    a, b, c = run(11), run(11), run(12)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert any(not np.allclose(x, z, atol=1e-6) for x, z in zip(a, c))


def test_motion_time_model_and_time_scale():
    slept = []
    robot = SimulatedUR5e(0, repeatability_mm=0.0, time_scale=0.5, sleep=slept.append)
    T = robot.tcp_pose()
    T[:3, 3] += [100.0, 0.0, 0.0]
    robot.move_linear(T, speed_mm_s=250.0, acceleration_mm_s2=1200.0)
    expected = trapezoid_time_s(100.0, 250.0, 1200.0)
    assert math.isclose(robot.sim_time_s, expected)
    assert slept == [pytest.approx(0.5 * expected)]


def test_rejected_poses_do_not_move_the_arm():
    ws = Workspace(lower_mm=(-700, -400, 100), upper_mm=(-200, 400, 700))
    robot = SimulatedUR5e(0, workspace=ws)
    q0 = robot.joints()
    T = robot.tcp_pose()
    outside = T.copy()
    outside[2, 3] = 50.0
    with pytest.raises(WorkspaceViolation, match="box"):
        robot.move_linear(outside)
    far = make_transform(T[:3, :3], [-1200.0, 0.0, 300.0])
    with pytest.raises(WorkspaceViolation, match="reach_mm"):
        SimulatedUR5e(0).move_linear(far)
    unreachable = make_transform(T[:3, :3], [-100.0, -50.0, 400.0])  # wrist inside the base column
    with pytest.raises(UnreachablePoseError):
        SimulatedUR5e(0).move_linear(unreachable)
    nan = T.copy()
    nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="T_base_tcp"):
        robot.move_linear(nan)
    with pytest.raises(ValueError, match="speed_mm_s"):
        robot.move_linear(T, speed_mm_s=0.0)
    with pytest.raises(ValueError, match="acceleration_mm_s2"):
        robot.move_linear(T, acceleration_mm_s2=2e5)
    assert np.array_equal(robot.joints(), q0)
    assert robot.state().moves_completed == 0


def test_disconnect_after_k_moves_then_reconnect():
    robot = SimulatedUR5e(0, repeatability_mm=0.0, faults=FaultPlan(disconnect_after_moves=2))
    targets = random_targets(robot, np.random.default_rng(6), 3)
    robot.move_linear(targets[0])
    reached = robot.move_linear(targets[1])
    assert not robot.state().connected
    for call in (robot.tcp_pose, robot.joints, robot.flange_pose, robot.stop, lambda: robot.move_linear(targets[2])):
        with pytest.raises(RobotConnectionError, match="not connected"):
            call()
    robot.reconnect()
    assert np.allclose(robot.tcp_pose(), reached)
    robot.move_linear(targets[2])
    assert robot.state().moves_completed == 3


def test_disconnect_mid_move_leaves_the_arm_halfway_and_unreadable():
    robot = SimulatedUR5e(0, repeatability_mm=0.0, faults=FaultPlan(disconnect_during_move=1))
    start = robot.tcp_pose()
    target = start.copy()
    target[:3, 3] += [80.0, 40.0, -60.0]
    with pytest.raises(RobotConnectionError, match="halfway"):
        robot.move_linear(target)
    with pytest.raises(RobotConnectionError):
        robot.tcp_pose()
    robot.reconnect()
    mid = 0.5 * (start[:3, 3] + target[:3, 3])  # symmetric profile: half the time, half the way
    assert np.linalg.norm(robot.tcp_pose()[:3, 3] - mid) < 0.5
    assert robot.state().moves_completed == 0


def test_protective_stop_mid_move_blocks_until_cleared():
    robot = SimulatedUR5e(0, repeatability_mm=0.0, faults=FaultPlan(protective_stop_during_move=1))
    target = robot.tcp_pose()
    target[:3, 3] += [60.0, 0.0, 0.0]
    with pytest.raises(ProtectiveStopError, match="protective stop"):
        robot.move_linear(target)
    stopped_at = robot.tcp_pose()
    assert robot.state().protective_stop and robot.state().connected
    with pytest.raises(ProtectiveStopError, match="clear it first"):
        robot.move_linear(target)
    assert np.array_equal(robot.tcp_pose(), stopped_at)
    robot.clear_protective_stop()
    assert np.abs(robot.move_linear(target) - target).max() < 1e-9


def test_slow_controller_times_out_without_moving():
    robot = SimulatedUR5e(0, faults=FaultPlan(command_delay_s=3.0), command_timeout_s=1.0)
    q0 = robot.joints()
    T = robot.tcp_pose()
    T[2, 3] += 10
    with pytest.raises(RobotTimeout, match="command_timeout_s=1.0"):
        robot.move_linear(T)
    assert np.array_equal(robot.joints(), q0)
    assert robot.sim_time_s == pytest.approx(1.0)
    ok = SimulatedUR5e(0, repeatability_mm=0.0, faults=FaultPlan(command_delay_s=0.5), command_timeout_s=1.0)
    assert np.abs(ok.move_linear(T) - T).max() < 1e-9


def test_tcp_offset_changes_what_is_aimed():
    robot = SimulatedUR5e(0, repeatability_mm=0.0)
    T = robot.tcp_pose()
    robot.set_tcp(T_FLANGE_TCP)
    assert np.allclose(robot.tcp_pose(), T @ T_FLANGE_TCP)
    target = T @ T_FLANGE_TCP
    target[:3, 3] += [0, 0, 30]
    robot.move_linear(target)
    assert np.allclose(robot.flange_pose(), target @ invert_transform(T_FLANGE_TCP), atol=1e-9)
    with pytest.raises(ValueError, match="T_flange_tcp"):
        robot.set_tcp(np.diag([2.0, 1, 1, 1]))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"repeatability_mm": -0.1}, "repeatability_mm"),
        ({"command_timeout_s": 0}, "command_timeout_s"),
        ({"initial_joints_rad": [0, 0, 0, 0, 0, 7]}, "initial_joints_rad"),
    ],
)
def test_bad_construction_is_rejected(kwargs, word):
    with pytest.raises(ValueError, match=word):
        SimulatedUR5e(0, **kwargs)


def test_rng_must_be_explicit():
    with pytest.raises(TypeError, match="rng"):
        SimulatedUR5e(None)
    with pytest.raises(ValueError, match="disconnect_after_moves"):
        FaultPlan(disconnect_after_moves=0)
