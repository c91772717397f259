"""The half turn about the transducer's axis (§II-B.4) in the lab's files and plans: a pose record
carries both readings (histostudy.pose.pose_record, half_turn_reading), and a target planned with a
pose's orientation takes the reading the robot reaches with less joint travel
(histostudy.lab.plan_targeting_either_reading), each checked against planning both readings here."""

from types import SimpleNamespace

import numpy as np
import pytest

import histostudy.pose.from_files as from_files
from histostudy.core import WORLD_FRAME
from histostudy.geometry import matrix_from_rotvec
from histostudy.lab import calibrate_from_poses, plan_targeting, plan_targeting_either_reading
from histostudy.lab.workflow import READINGS
from histostudy.pose import half_turn_reading, pose_record
from histostudy.robot import UnreachablePoseError, Workspace, WorkspaceViolation
from histostudy.study.targeting._calibration import calibration_poses
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth, start_joints
from histostudy.transducer import HALF_TURN, Feature, TransducerModel


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(21)
    truth = draw_ground_truth(rng, TargetingStudyConfig(n_experiments=1, background="none"))
    F = calibration_poses(rng, TargetingStudyConfig(n_experiments=1, background="none"), truth)
    records = [{"T_carm_transducer": truth.T_carm_transducer(f), "accepted": True} for f in F]
    calibration = calibrate_from_poses(records, F)
    target = truth.T_carm_phantom[:3, 3] + np.array([4.0, -3.0, 6.0])
    return SimpleNamespace(calibration=calibration, target=target, q0=start_joints(truth),
                           T=records[1]["T_carm_transducer"])


def _turned(T):
    out = np.array(T, dtype=float)
    out[:3, :3] = out[:3, :3] @ HALF_TURN
    return out


def _angle_deg(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def test_the_half_turn_reading_keeps_the_focal_point_and_the_axis(setup):
    reading = half_turn_reading(setup.T)
    turned = np.asarray(reading["T_carm_transducer_half_turn"])
    np.testing.assert_allclose(turned[:3, 3], setup.T[:3, 3])  # the focal point: the transducer frame's origin
    np.testing.assert_allclose(turned[:3, 2], setup.T[:3, 2], atol=1e-12)
    np.testing.assert_allclose(reading["axis_carm"], setup.T[:3, 2])
    assert np.linalg.norm(reading["axis_carm"]) == pytest.approx(1.0)
    assert _angle_deg(setup.T[:3, :3], turned[:3, :3]) == pytest.approx(180.0)
    # the half turn of the half turn is the record itself
    np.testing.assert_allclose(half_turn_reading(turned)["T_carm_transducer_half_turn"], setup.T, atol=1e-12)
    # a pose 179.9 deg from another about the axis: after the half turn, 0.1 deg
    near = setup.T.copy()
    near[:3, :3] = setup.T[:3, :3] @ matrix_from_rotvec([0, 0, np.radians(179.9)])
    assert _angle_deg(setup.T[:3, :3], np.asarray(half_turn_reading(near)["T_carm_transducer_half_turn"])[:3, :3]) \
        == pytest.approx(0.1, abs=1e-6)


def test_a_pose_record_states_its_frame_and_both_readings(setup):
    verdict = SimpleNamespace(ok=True, reasons=[], rms_distance_px=[0.5, 0.6], view_disagreement_mm=0.2,
                              view_gain_px2=[0.003, 0.004], unexplained_fraction=[0.01, 0.02])
    result = SimpleNamespace(T_carm_transducer=setup.T, focal_point_mm=setup.T[:3, 3], cost=1.0, verdict=verdict,
                             timings_s={"total": 1.0})
    record = pose_record(result, ["A.dcm", "B.dcm"])  # as every caller calls it: the digital model
    assert record["frame"] == WORLD_FRAME and record["units"] == {"length": "mm"}
    assert record["frames"] == ["A.dcm", "B.dcm"] and record["accepted"] is True
    assert record["verdict"]["view_gain_px2"] == [0.003, 0.004]  # what each view's own move would gain
    assert record["half_turn"]["symmetric"] is True  # the paper's transducer
    np.testing.assert_allclose(record["half_turn"]["T_carm_transducer_half_turn"], _turned(setup.T))


@pytest.fixture(scope="module")
def models():
    digital = TransducerModel.build(spacing_mm=0.47)
    screws = digital.points[Feature.SCREWS].copy()
    screws[screws[:, 0] > 0, 1] += 3.0  # the screws on one side moved: no longer its own half turn
    asymmetric = TransducerModel(spec=digital.spec, spacing_mm=digital.spacing_mm,
                                 points={**digital.points, Feature.SCREWS: screws}, weights=digital.weights,
                                 grid_step_mm=digital.grid_step_mm)
    return digital, asymmetric


def test_an_asymmetric_model_says_so_and_each_model_is_checked_once(setup, models, monkeypatch):
    digital, asymmetric = models
    calls = []
    real = from_files.half_turn_symmetric
    monkeypatch.setattr(from_files, "half_turn_symmetric", lambda model: calls.append(model) or real(model))
    assert half_turn_reading(setup.T, asymmetric)["symmetric"] is False
    assert half_turn_reading(setup.T, digital)["symmetric"] is True
    for _ in range(3):
        half_turn_reading(setup.T, asymmetric)
        half_turn_reading(setup.T, digital)
    assert calls == [asymmetric, digital]
    with pytest.raises(TypeError, match="model must be a TransducerModel"):
        half_turn_reading(setup.T, "digital")
    with pytest.raises(ValueError, match="T_carm_transducer must be a finite 4x4"):
        half_turn_reading(np.eye(3))


def _both(setup, T, **options):
    options = {"start_joints_rad": setup.q0, **options}
    return {reading: plan_targeting(setup.calibration, setup.target, orientation=R, **options)
            for reading, R in zip(READINGS, (T[:3, :3], T[:3, :3] @ HALF_TURN))}


@pytest.mark.parametrize("record", ["as estimated", "turned half"])
def test_the_reading_of_smaller_joint_travel_is_planned(setup, record):
    T = setup.T if record == "as estimated" else _turned(setup.T)
    both = _both(setup, T)
    smaller = min(READINGS, key=lambda r: both[r].joint_travel_rad)
    plan = plan_targeting_either_reading(setup.calibration, setup.target, T, start_joints_rad=setup.q0)
    assert plan.orientation_reading == smaller
    assert plan.joint_travel_rad == pytest.approx(min(p.joint_travel_rad for p in both.values()))
    np.testing.assert_allclose(plan.joints_rad, both[smaller].joints_rad)
    np.testing.assert_allclose(plan.R_carm_transducer[:, 2], T[:3, 2], atol=1e-12)  # the beam axis is kept
    assert f"{both[smaller].joint_travel_rad:.3f} rad" in plan.orientation_reason
    # whichever reading the estimate gave, the robot is sent to the same orientation
    other = plan_targeting_either_reading(setup.calibration, setup.target, _turned(T), start_joints_rad=setup.q0)
    np.testing.assert_allclose(other.R_carm_transducer, plan.R_carm_transducer, atol=1e-12)
    assert other.orientation_reading != plan.orientation_reading
    assert plan.to_dict()["orientation_reading"] == smaller


def test_starting_where_the_half_turn_lies_picks_the_half_turn(setup):
    both = _both(setup, setup.T)
    start = both["half turn"].joints_rad  # the robot already holds the half turn: no travel
    plan = plan_targeting_either_reading(setup.calibration, setup.target, setup.T, start_joints_rad=start)
    assert plan.orientation_reading == "half turn" and plan.joint_travel_rad == pytest.approx(0.0, abs=1e-9)
    # a transducer that is not its own half turn keeps its orientation, whatever the travel
    kept = plan_targeting_either_reading(setup.calibration, setup.target, setup.T, start_joints_rad=start,
                                         symmetric=False)
    assert kept.orientation_reading == "as recorded" and kept.joint_travel_rad > 1.0
    np.testing.assert_allclose(kept.R_carm_transducer, setup.T[:3, :3], atol=1e-12)
    assert "not ambiguous" in kept.orientation_reason
    unsaid = plan_targeting_either_reading(setup.calibration, setup.target, setup.T, start_joints_rad=start,
                                           symmetric=None)
    assert unsaid.orientation_reading == "half turn" and "does not say" in unsaid.orientation_reason


def test_a_reading_out_of_reach_is_passed_over_and_none_in_reach_is_refused(setup):
    both = _both(setup, setup.T)
    shoulder = np.array(Workspace().shoulder_mm)
    reach = {r: np.linalg.norm(p.T_base_flange[:3, 3] - shoulder) for r, p in both.items()}
    far = max(reach, key=reach.get)
    near = next(r for r in READINGS if r != far)
    assert reach[far] - reach[near] > 1.0  # the mount is off the axis: the half turn moves the flange
    # start on the far reading (no travel for it), with a reach between the two flanges
    limited = Workspace(reach_mm=float(np.mean(list(reach.values()))))
    plan = plan_targeting_either_reading(setup.calibration, setup.target, setup.T, workspace=limited,
                                         start_joints_rad=both[far].joints_rad)
    assert plan.orientation_reading == near and "WorkspaceViolation" in plan.orientation_reason
    with pytest.raises(WorkspaceViolation, match="neither reading"):
        plan_targeting_either_reading(setup.calibration, setup.target, setup.T, start_joints_rad=setup.q0,
                                      workspace=Workspace(reach_mm=min(reach.values()) - 1.0))
    with pytest.raises(UnreachablePoseError, match="as recorded: .*half turn: "):
        plan_targeting_either_reading(setup.calibration, setup.target + [1500.0, 0, 0], setup.T,
                                      start_joints_rad=setup.q0)
    with pytest.raises(ValueError, match="symmetric must be"):
        plan_targeting_either_reading(setup.calibration, setup.target, setup.T, symmetric="yes")
    with pytest.raises(ValueError, match="T_carm_transducer must be"):
        plan_targeting_either_reading(setup.calibration, setup.target, "down")
