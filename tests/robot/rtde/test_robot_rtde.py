"""RTDERobot through the real ur_rtde client (1.6.5) against the simulated controller on loopback.

Every controller runs in its own process (``python -m histostudy.robot.controller``) on its own
loopback address (the client's ports are fixed), started by a fixture and killed in teardown.
Each test is bounded in time by SIGALRM (no pytest plugin), with a faulthandler backstop.

The tests that drop or kill the controller under a connected client run in a child pytest process
(:func:`isolated`): after a drop, ur_rtde's control interface reconnects on its own C++ thread, and
when that fails it terminates the whole process (docs/robot.md, "The RTDE client").
Three of about ten full test runs under load were aborted so. A child killed by a signal is run
again, at most twice; a child that fails an assertion fails the test at once.
"""

import faulthandler
import functools
import importlib.metadata
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.robot import (
    ProtectiveStopError,
    Robot,
    RobotConnectionError,
    RobotTimeout,
    RTDERobot,
    SimulatedUR5e,
    UnreachablePoseError,
    Workspace,
    WorkspaceViolation,
    forward_kinematics,
    pose_from_transform,
    transform_from_pose,
)
from histostudy.robot.controller._process import ControllerProcess

TEST_TIMEOUT_S = 30
T_FLANGE_TCP = make_transform(matrix_from_rotvec([0.0, 0.0, 0.4]), [5.0, -3.0, 120.0])
# One address block per test process, so that concurrent runs on one machine do not collide.
_BLOCK = 20 + os.getpid() % 200
_next = iter(range(1, 250))


def new_host() -> str:
    return f"127.{_BLOCK}.{next(_next)}.1"


_CHILD = "HISTOSTUDY_RTDE_TEST_CHILD"
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))  # pytest's rootdir
ISOLATED_ATTEMPTS = 3


def isolated(test):
    """Run ``test`` in a child pytest process (module docstring); in the child, run it as it is."""

    @functools.wraps(test)
    def in_a_child(*args, **kwargs):
        if os.environ.get(_CHILD):
            return test(*args, **kwargs)
        node = os.environ["PYTEST_CURRENT_TEST"].rsplit(" (", 1)[0]
        signal.alarm(0)
        faulthandler.cancel_dump_traceback_later()
        faulthandler.dump_traceback_later(ISOLATED_ATTEMPTS * (TEST_TIMEOUT_S + 30) + 30, exit=True)
        outputs = []
        for _ in range(ISOLATED_ATTEMPTS):
            child = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", node],
                                   env={**os.environ, _CHILD: "1"}, cwd=ROOT, capture_output=True, text=True,
                                   timeout=TEST_TIMEOUT_S + 30)
            if child.returncode == 0:
                return
            outputs.append(child.stdout[-3000:] + child.stderr[-2000:])
            if child.returncode > 0:  # the test failed: no second try
                pytest.fail(f"{node} failed in its child process:\n{outputs[-1]}")
        pytest.fail(f"{node}: the child process was killed by a signal {ISOLATED_ATTEMPTS} times "
                    f"(last exit status {child.returncode}):\n{outputs[-1]}")

    return in_a_child


@pytest.fixture(autouse=True)
def time_limit():
    """Fail a test that runs longer than TEST_TIMEOUT_S (and kill the run if even that hangs)."""

    def on_alarm(signum, frame):
        raise TimeoutError(f"test exceeded {TEST_TIMEOUT_S} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(TEST_TIMEOUT_S)
    faulthandler.dump_traceback_later(TEST_TIMEOUT_S + 30, exit=True)
    try:
        yield
    finally:
        signal.alarm(0)
        faulthandler.cancel_dump_traceback_later()
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def controller(request):
    """A fresh controller; extra CLI arguments via
    ``@pytest.mark.parametrize('controller', [[...]], indirect=True)``."""
    args = getattr(request, "param", ["--repeatability-mm", "0"])
    proc = ControllerProcess(new_host(), *args, max_lifetime_s=120)
    yield proc
    proc.kill()


@pytest.fixture(scope="module")
def shared_controller():
    proc = ControllerProcess(new_host(), "--repeatability-mm", "0", max_lifetime_s=300)
    yield proc
    proc.kill()


@pytest.fixture
def robot(shared_controller):
    r = RTDERobot(shared_controller.host, command_timeout_s=5.0)
    yield r
    r.close()


def walk(T_start, rng, n, step_mm=40.0, tilt_rad=0.15):
    T = T_start
    out = []
    for _ in range(n):
        T = make_transform(T[:3, :3] @ matrix_from_rotvec(rng.uniform(-tilt_rad, tilt_rad, 3)),
                           T[:3, 3] + rng.uniform(-step_mm, step_mm, 3))
        out.append(T)
    return out


def test_ur_rtde_is_the_pinned_version():
    version = importlib.metadata.version("ur_rtde")
    assert version == "1.6.5", (
        f"ur_rtde {version} is installed, but the simulated controller implements the register protocol "
        f"of ur_rtde 1.6.5 (command numbers, recipes, handshake). Pin ur-rtde==1.6.5 or re-derive the "
        f"protocol in histostudy/robot/controller/_protocol.py and _program.py for the new version."
    )


def test_pose_conversion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(20):
        T = make_transform(matrix_from_rotvec(rng.uniform(-2, 2, 3)), rng.uniform(-800, 800, 3))
        pose = pose_from_transform(T)
        assert np.allclose(np.asarray(pose[:3]) * 1000.0, T[:3, 3])
        assert np.allclose(transform_from_pose(pose), T, atol=1e-12)
    with pytest.raises(ValueError, match="pose"):
        transform_from_pose([0, 0, float("nan"), 0, 0, 0])


def test_unreachable_host_fails_at_once_with_a_clear_error():
    host = new_host()  # nothing listens here
    t0 = time.monotonic()
    with pytest.raises(RobotConnectionError, match=f"{host}:30004"):
        RTDERobot(host, connect_timeout_s=1.0)
    assert time.monotonic() - t0 < 3.0
    # The fact the probe guards: the bare client raises RuntimeError immediately too.
    import rtde_receive

    with pytest.raises(RuntimeError, match="Could not connect"):
        rtde_receive.RTDEReceiveInterface(host)


def test_connect_set_tcp_move_and_read_back(robot):
    assert isinstance(robot, Robot)
    robot.set_tcp(T_FLANGE_TCP)
    assert np.allclose(robot.tcp_offset(), T_FLANGE_TCP)
    T_now = robot.tcp_pose()
    # Readback consistency: the controller's TCP pose equals local FK of its joints times the TCP.
    assert np.allclose(forward_kinematics(robot.joints()) @ T_FLANGE_TCP, T_now, atol=1e-9)
    assert np.allclose(robot.flange_pose() @ T_FLANGE_TCP, T_now, atol=1e-9)
    for T in walk(T_now, np.random.default_rng(1), 4):
        reached = robot.move_linear(T, speed_mm_s=200, acceleration_mm_s2=1000)
        assert np.abs(reached - T).max() < 1e-6
        assert np.allclose(robot.tcp_pose(), reached)
    state = robot.state()
    assert state.connected and state.steady and not state.protective_stop and state.moves_completed == 4


@pytest.mark.parametrize("repeatability", [0.0, 0.03])
def test_same_seeded_sequence_same_poses_as_the_in_process_simulation(repeatability):
    seed = 7
    proc = ControllerProcess(new_host(), "--seed", str(seed), "--repeatability-mm", str(repeatability),
                             max_lifetime_s=120)
    try:
        real = RTDERobot(proc.host)
        sim = SimulatedUR5e(seed, repeatability_mm=repeatability)
        real.set_tcp(T_FLANGE_TCP)
        sim.set_tcp(T_FLANGE_TCP)
        assert np.abs(real.tcp_pose() - sim.tcp_pose()).max() < 1e-9
        for T in walk(sim.tcp_pose(), np.random.default_rng(3), 6):
            a = real.move_linear(T, 300, 2000)
            b = sim.move_linear(T, 300, 2000)
            assert np.abs(a[:3, 3] - b[:3, 3]).max() < 1e-6
            assert np.abs(a[:3, :3] - b[:3, :3]).max() < 1e-9
            assert np.abs(real.joints() - sim.joints()).max() < 1e-9
            assert np.linalg.norm(a[:3, 3] - T[:3, 3]) <= repeatability + 1e-9
        real.close()
    finally:
        proc.kill()


def test_every_pose_is_checked_before_moving(robot):
    robot.set_tcp(np.eye(4))
    q0 = robot.joints()
    T = robot.tcp_pose()
    nan = T.copy()
    nan[1, 3] = np.nan  # the client itself would pass a NaN pose through
    with pytest.raises(ValueError, match="T_base_tcp"):
        robot.move_linear(nan)
    with pytest.raises(ValueError, match="speed_mm_s"):
        robot.move_linear(T, speed_mm_s=3500)
    with pytest.raises(UnreachablePoseError):
        robot.move_linear(make_transform(T[:3, :3], [-100.0, -50.0, 400.0]))
    with pytest.raises(WorkspaceViolation, match="reach_mm"):
        robot.move_linear(make_transform(T[:3, :3], [-1200.0, 0.0, 300.0]))
    across = T.copy()
    across[:2, 3] = -T[:2, 3]  # reachable, but the straight line there crosses the base axis
    with pytest.raises(UnreachablePoseError, match="straight path"):
        robot.move_linear(across)
    boxed = RTDERobot(robot.host, workspace=Workspace(lower_mm=(-700, -400, 450), upper_mm=(-200, 400, 700)))
    low = T.copy()
    low[2, 3] = 300.0
    with pytest.raises(WorkspaceViolation, match="box"):
        boxed.move_linear(low)
    boxed.close()
    assert np.array_equal(robot.joints(), q0)


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--workspace-box",
                                          "-700", "-400", "450", "-200", "400", "700"]], indirect=True)
def test_controller_safety_limits_are_consulted(controller):
    robot = RTDERobot(controller.host)  # the client's own workspace allows the pose ...
    T = robot.tcp_pose()
    T[2, 3] = 300.0
    with pytest.raises(WorkspaceViolation, match="controller .* safety limits"):
        robot.move_linear(T)  # ... the controller's does not
    assert robot.state().moves_completed == 0
    robot.close()


def test_protective_stop_blocks_moves_until_cleared(shared_controller):
    robot = RTDERobot(shared_controller.host)
    target = robot.tcp_pose()
    target[:3, 3] += [20.0, 0.0, 0.0]
    robot.trigger_protective_stop()
    assert robot.state().protective_stop
    with pytest.raises(ProtectiveStopError, match="protective stop"):
        robot.move_linear(target)
    robot.stop()  # allowed, and harmless, under a protective stop
    robot.clear_protective_stop()
    assert not robot.state().protective_stop
    assert np.abs(robot.move_linear(target) - target).max() < 1e-6
    robot.close()


def test_a_move_answered_false_for_a_protective_stop_says_where_the_arm_stopped(shared_controller):
    # The stop may reach the client before moveL's answer (then moveL returns False) or after it:
    # either way the error says where the arm is. Here the first case, made certain.
    robot = RTDERobot(shared_controller.host)
    here = robot.tcp_pose()
    target = here.copy()
    target[:3, 3] += [20.0, 0.0, 0.0]

    class StoppedOnMove:
        def __init__(self, control):
            self._inner = control

        def __getattr__(self, name):
            return getattr(self._inner, name)

        def moveL(self, *args):
            robot.trigger_protective_stop()
            return False

    robot._control = StoppedOnMove(robot._control)
    where = np.round(here[:3, 3], 3).tolist()
    with pytest.raises(ProtectiveStopError, match=re.escape(f"moveL failed: the arm at {shared_controller.host} is "
                                                            f"in a protective stop; it stopped at {where} mm")):
        robot.move_linear(target)
    robot._control = robot._control._inner
    robot.clear_protective_stop()
    assert np.abs(robot.move_linear(target) - target).max() < 1e-6
    robot.close()


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--time-scale", "1",
                                          "--protective-stop-during-move", "1"]], indirect=True)
def test_injected_protective_stop_during_a_move(controller):
    robot = RTDERobot(controller.host)
    start = robot.tcp_pose()
    target = start.copy()
    target[:3, 3] += [40.0, 0.0, 0.0]
    with pytest.raises(ProtectiveStopError, match="stopped at"):
        robot.move_linear(target, speed_mm_s=250, acceleration_mm_s2=2500)
    stopped = robot.tcp_pose()
    assert robot.state().protective_stop and robot.state().steady
    assert 5.0 < stopped[0, 3] - start[0, 3] < 35.0  # stopped part way
    robot.close()


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--disconnect-after-moves", "2"]], indirect=True)
@isolated
def test_disconnect_after_k_moves_then_reconnect(controller):
    robot = RTDERobot(controller.host)
    targets = walk(robot.tcp_pose(), np.random.default_rng(4), 3)
    robot.move_linear(targets[0])
    reached = robot.move_linear(targets[1])
    with pytest.raises(RobotConnectionError, match="dropped|not connected"):
        robot.move_linear(targets[2])
    assert not robot.state().connected
    for read in (robot.tcp_pose, robot.joints, robot.flange_pose):
        with pytest.raises(RobotConnectionError):
            read()
    robot.reconnect()
    assert np.abs(robot.tcp_pose() - reached).max() < 1e-6  # the arm stayed where it was
    assert np.abs(robot.move_linear(targets[2]) - targets[2]).max() < 1e-6
    robot.close()


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--time-scale", "1",
                                          "--disconnect-during-move", "1"]], indirect=True)
@isolated
def test_disconnect_mid_move_gives_no_stale_pose(controller):
    robot = RTDERobot(controller.host)
    start = robot.tcp_pose()
    target = start.copy()
    target[:3, 3] += [40.0, 0.0, 0.0]
    with pytest.raises(RobotConnectionError, match="dropped"):
        robot.move_linear(target, speed_mm_s=250, acceleration_mm_s2=2500)
    with pytest.raises(RobotConnectionError):
        robot.tcp_pose()
    robot.reconnect()
    halfway = 0.5 * (start[:3, 3] + target[:3, 3])
    assert np.linalg.norm(robot.tcp_pose()[:3, 3] - halfway) < 0.5
    robot.close()


@isolated
def test_killed_controller_idle_gives_a_clear_error_not_stale_data(controller):
    robot = RTDERobot(controller.host, command_timeout_s=2.0)
    robot.tcp_pose()
    controller.kill()
    t0 = time.monotonic()
    deadline = t0 + 3.0
    # The receive interface notices the closed socket within moments; until then the pose is the
    # last real one, after it every reading fails.
    while True:
        try:
            robot.tcp_pose()
        except RobotConnectionError as exc:
            assert "dropped" in str(exc) or "not connected" in str(exc)
            break
        assert time.monotonic() < deadline, "a pose was still returned 3 s after the controller died"
        time.sleep(0.01)
    assert time.monotonic() - t0 < 2.0 + 3.0
    assert not robot.state().connected
    with pytest.raises(RobotConnectionError):
        robot.move_linear(np.eye(4))


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--time-scale", "1"]], indirect=True)
@isolated
def test_killed_controller_mid_move_ends_within_the_watchdog(controller):
    robot = RTDERobot(controller.host, move_timeout_margin_s=2.0)
    target = robot.tcp_pose()
    target[:3, 3] += [60.0, 0.0, 0.0]
    killer = threading.Timer(0.2, controller.kill)
    killer.start()
    t0 = time.monotonic()
    with pytest.raises((RobotConnectionError, RobotTimeout)):
        robot.move_linear(target, speed_mm_s=30, acceleration_mm_s2=500)  # ~2.1 s of motion
    assert time.monotonic() - t0 < 2.0 * 2.1 + 2.0 + 1.5
    killer.join()
    with pytest.raises(RobotConnectionError):
        robot.tcp_pose()


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--command-delay-s", "2.5"]], indirect=True)
@isolated
def test_slow_controller_times_out(controller):
    t0 = time.monotonic()
    with pytest.raises(RobotTimeout, match="within 0.8 s"):
        RTDERobot(controller.host, command_timeout_s=0.8)  # its first command (setTcp) is late
    assert time.monotonic() - t0 < 0.8 + 3.0


def test_controller_inverse_kinematics_through_the_client(robot):
    """The IK queries RTDERobot relies on, asked through the unmodified client."""
    robot.set_tcp(np.eye(4))
    control = robot._control
    T = robot.tcp_pose()
    T[:3, 3] += [30.0, -20.0, 10.0]
    q_now = robot.joints()
    assert control.getInverseKinematicsHasSolution(pose_from_transform(T))
    assert control.getInverseKinematicsHasSolution(pose_from_transform(T), list(q_now))
    q = np.asarray(control.getInverseKinematics(pose_from_transform(T), list(q_now)))
    assert np.allclose(forward_kinematics(q), T, atol=1e-9)
    assert np.linalg.norm(q - q_now) < 0.5  # the solution near the current configuration
    far = make_transform(T[:3, :3], [-1500.0, 0.0, 300.0])
    assert not control.getInverseKinematicsHasSolution(pose_from_transform(far))
    assert not control.isPoseWithinSafetyLimits(pose_from_transform(far))


@pytest.mark.parametrize("controller", [["--repeatability-mm", "0", "--time-scale", "1"]], indirect=True)
def test_stop_halts_a_running_move(controller):
    robot = RTDERobot(controller.host)
    start = robot.tcp_pose()
    target = start.copy()
    target[:3, 3] += [60.0, 0.0, 0.0]
    # An asynchronous moveL (1.1 s at 60 mm/s) is the way to have a move to stop.
    assert robot._control.moveL(pose_from_transform(target), 0.06, 0.6, True)
    time.sleep(0.4)
    robot.stop()
    time.sleep(0.1)
    stopped = robot.tcp_pose()
    assert robot.state().steady
    assert 5.0 < stopped[0, 3] - start[0, 3] < 55.0
    time.sleep(0.3)
    assert np.array_equal(robot.tcp_pose(), stopped)  # it stays stopped
    robot.close()
