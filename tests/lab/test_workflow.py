"""histostudy.lab.workflow: pose records and flange poses to a checked calibration, a target to a
checked move, on an exact synthetic set-up of the targeting study (its ground truth known)."""

import json

import numpy as np
import pytest

from histostudy.calibration import HALF_TURN, CalibrationError
from histostudy.geometry import make_transform
from histostudy.imaging import Volume
from histostudy.lab import (
    TargetingPlan,
    calibrate_from_poses,
    execute_targeting,
    load_flange_poses,
    load_pose_record,
    plan_targeting,
)
from histostudy.robot import SimulatedUR5e, UnreachablePoseError, Workspace, WorkspaceViolation, pose_from_transform
from histostudy.study.targeting._calibration import calibration_poses
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth, start_joints


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(21)
    config = TargetingStudyConfig(n_experiments=1, background="none")
    truth = draw_ground_truth(rng, config)
    F = calibration_poses(rng, config, truth)
    records = [{"T_carm_transducer": truth.T_carm_transducer(f), "accepted": True} for f in F]
    return truth, F, records


def test_the_calibration_recovers_the_true_chain_through_half_turned_estimates(setup):
    truth, F, records = setup
    # The estimator read station 2 half turned (the transducer looks the same): still the true chain.
    read = [dict(r) for r in records]
    read[2]["T_carm_transducer"] = read[2]["T_carm_transducer"] @ HALF_TURN
    cal = calibrate_from_poses(read, F, nominal_T_flange_transducer=truth.T_flange_transducer_nominal)
    np.testing.assert_allclose(cal.T_carm_base, truth.T_carm_base, atol=1e-6)
    np.testing.assert_allclose(cal.T_flange_transducer, truth.T_flange_transducer, atol=1e-6)


def test_refused_or_unpaired_stations_and_a_loose_chain_are_refused(setup):
    truth, F, records = setup
    refused = [dict(r) for r in records]
    refused[1]["accepted"] = False
    with pytest.raises(ValueError, match=r"pose_records \[1\]: the pose estimate's verdict refused"):
        calibrate_from_poses(refused, F)
    with pytest.raises(ValueError, match="pair up station by station, got 4 pose records and 3"):
        calibrate_from_poses(records, F[:3])
    # One station 5 mm off: the residual gate refuses the calibration.
    off = [dict(r) for r in records]
    off[3]["T_carm_transducer"] = off[3]["T_carm_transducer"] @ make_transform(np.eye(3), [5.0, 0.0, 0.0])
    with pytest.raises(CalibrationError, match="focal-point residual"):
        calibrate_from_poses(off, F)


def test_flange_poses_read_as_transforms_or_ur_poses(tmp_path, setup):
    _, F, _ = setup
    (tmp_path / "mm.json").write_text(json.dumps({"T_base_flange": [f.tolist() for f in F]}))
    (tmp_path / "ur.json").write_text(json.dumps({"ur_pose": [pose_from_transform(f) for f in F]}))
    for name in ("mm.json", "ur.json"):
        np.testing.assert_allclose(load_flange_poses(tmp_path / name), F, atol=1e-9)
    (tmp_path / "bad.json").write_text(json.dumps({"poses": []}))
    with pytest.raises(ValueError, match="'T_base_flange'.*'ur_pose'"):
        load_flange_poses(tmp_path / "bad.json")
    (tmp_path / "skew.json").write_text(json.dumps({"T_base_flange": [np.diag([2.0, 1, 1, 1]).tolist()]}))
    with pytest.raises(ValueError, match=r"T_base_flange\[0\]"):
        load_flange_poses(tmp_path / "skew.json")
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_flange_poses(tmp_path / "missing.json")
    (tmp_path / "pose.json").write_text(json.dumps({"focal_point_mm": [0, 0, 0]}))
    with pytest.raises(ValueError, match="'T_carm_transducer' and 'accepted'"):
        load_pose_record(tmp_path / "pose.json")


def test_a_planned_target_is_reached_by_the_true_chain_and_the_robot_moves_only_on_execute(setup):
    truth, F, records = setup
    cal = calibrate_from_poses(records, F)
    target = truth.T_carm_phantom[:3, 3] + np.array([4.0, -3.0, 6.0])
    q0 = start_joints(truth)
    volume = Volume.from_bounds(target - 40, target + 40, 2.0)
    plan = plan_targeting(cal, target, volume=volume, start_joints_rad=q0)
    assert isinstance(plan, TargetingPlan)
    robot = SimulatedUR5e(0, repeatability_mm=0.0, initial_joints_rad=q0)
    assert robot.state().moves_completed == 0  # planning moved nothing
    done = execute_targeting(plan, robot, speed_mm_s=100.0)
    assert robot.state().moves_completed == 1 and done["position_error_mm"] < 1e-6
    # Through the TRUE chain the transducer's focal point sits on the target, pointing down.
    T_true = truth.T_carm_transducer(robot.flange_pose())
    assert np.linalg.norm(T_true[:3, 3] - target) < 1e-6
    assert T_true[1, 2] == pytest.approx(-1.0)  # +z (towards the transducer) is world -y: up
    # The plan was made from q0: after the move the robot is elsewhere, and the plan is refused.
    with pytest.raises(ValueError, match="plan again from where it is"):
        execute_targeting(plan, robot)
    assert robot.state().moves_completed == 1
    json.dumps(plan.to_dict())  # plain JSON


def test_targets_outside_the_cbct_the_reach_or_the_workspace_are_refused_before_moving(setup):
    truth, F, records = setup
    cal = calibrate_from_poses(records, F)
    centre = truth.T_carm_phantom[:3, 3]
    q0 = start_joints(truth)
    with pytest.raises(ValueError, match="outside the CBCT volume"):
        plan_targeting(cal, centre + 100, volume=Volume.from_bounds(centre - 40, centre + 40, 2.0))
    with pytest.raises(UnreachablePoseError):
        plan_targeting(cal, centre + np.array([1500.0, 0, 0]), start_joints_rad=q0)
    with pytest.raises(WorkspaceViolation):
        plan_targeting(cal, centre, start_joints_rad=q0, workspace=Workspace(center_mm=(0, 0, 0), radius_mm=10.0))
    with pytest.raises(ValueError, match="target_mm must be 3 finite"):
        plan_targeting(cal, [np.nan, 0, 0])
    with pytest.raises(ValueError, match="orientation must be 'down'"):
        plan_targeting(cal, centre, orientation="up")
