"""Workspace, motion parameters and the motion-time model (histostudy.robot.base)."""

import math

import numpy as np
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.robot import base as b


def _pose(p):
    return make_transform(t_mm=p)


def test_box_and_sphere_and_reach():
    ws = b.Workspace(lower_mm=(-600, -300, 0), upper_mm=(0, 300, 600), center_mm=(-400, 0, 300), radius_mm=250)
    assert ws.violation(_pose([-400, 0, 300]), _pose([-400, 0, 300])) is None
    assert "box" in ws.violation(_pose([50, 0, 300]), _pose([0, 0, 300]))
    assert "sphere" in ws.violation(_pose([-590, 290, 300]), _pose([-400, 0, 300]))
    far = b.Workspace()
    assert far.violation(_pose([0, 0, 0]), _pose([0, 0, 162.5 + 851])) is not None
    assert far.violation(_pose([0, 0, 0]), _pose([0, 0, 162.5 + 849])) is None
    with pytest.raises(b.WorkspaceViolation, match="reach_mm=850"):
        far.check(_pose([0, 0, 0]), _pose([900, 0, 162.5]))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"lower_mm": (0, 0, 0)}, "together"),
        ({"lower_mm": (0, 0, 0), "upper_mm": (1, -1, 1)}, "below"),
        ({"center_mm": (0, 0, 0), "radius_mm": -1.0}, "radius_mm"),
        ({"reach_mm": float("nan")}, "reach_mm"),
        ({"center_mm": (0, 0), "radius_mm": 1.0}, "center_mm"),
    ],
)
def test_workspace_rejects_bad_configuration(kwargs, word):
    with pytest.raises(ValueError, match=word):
        b.Workspace(**kwargs)


@pytest.mark.parametrize("v, a", [(0, 1000), (3001, 1000), (100, 0), (100, 150001), (float("nan"), 1),
                                  (1, float("inf"))])
def test_motion_parameters_outside_the_ur_rtde_range_are_rejected(v, a):
    with pytest.raises(ValueError, match="speed_mm_s|acceleration_mm_s2"):
        b.check_motion_parameters(v, a)


def test_trapezoid_time_is_continuous_and_matches_closed_form():
    v, a = 250.0, 1200.0
    d_switch = v * v / a  # where the triangle becomes a trapezoid
    assert math.isclose(b.trapezoid_time_s(d_switch * (1 - 1e-9), v, a), b.trapezoid_time_s(d_switch, v, a),
                        rel_tol=1e-6)
    assert math.isclose(b.trapezoid_time_s(100.0, v, a), 100 / v + v / a)
    assert math.isclose(b.trapezoid_time_s(10.0, v, a), 2 * math.sqrt(10 / a))
    assert b.trapezoid_time_s(0.0, v, a) == 0.0


@pytest.mark.parametrize("distance", [5.0, 52.0, 300.0])
def test_trapezoid_fraction_is_monotonic_and_integrates_the_profile(distance):
    v, a = 250.0, 1200.0
    T = b.trapezoid_time_s(distance, v, a)
    t = np.linspace(0, T, 2001)
    s = np.array([b.trapezoid_fraction(ti, T, distance, v, a) for ti in t])
    assert s[0] == 0.0 and s[-1] == 1.0
    assert np.all(np.diff(s) >= -1e-12)
    speed = np.diff(s) * distance / np.diff(t)
    assert speed.max() <= v * (1 + 1e-3)
    # Symmetric profile: half the time covers half the distance.
    assert math.isclose(b.trapezoid_fraction(T / 2, T, distance, v, a), 0.5, abs_tol=1e-9)


def test_linear_motion_time_takes_the_slower_of_translation_and_rotation():
    T0 = np.eye(4)
    T_trans = _pose([100.0, 0, 0])
    assert math.isclose(b.linear_motion_time_s(T0, T_trans, 250, 1200), 100 / 250 + 250 / 1200)
    T_rot = make_transform(matrix_from_rotvec([0, 0, 1.0]))
    expected = b.trapezoid_time_s(1.0, b.ROTATION_SPEED_RAD_S, b.ROTATION_ACCELERATION_RAD_S2)
    assert math.isclose(b.linear_motion_time_s(T0, T_rot, 250, 1200), expected)


def test_error_hierarchy():
    for cls in (b.RobotConnectionError, b.ProtectiveStopError, b.UnreachablePoseError, b.WorkspaceViolation,
                b.RobotTimeout):
        assert issubclass(cls, b.RobotError)
    assert issubclass(b.RobotTimeout, TimeoutError)
