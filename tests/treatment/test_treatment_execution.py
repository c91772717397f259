"""Tests of histostudy.treatment.execution: the plan executed on the simulated UR5e with a journal
that resumes where a fault stopped it (§II-D)."""

import numpy as np
import pytest
from treatment_setup import R_CT, robot_zone_and_calibration

from histostudy.geometry import transform_points
from histostudy.robot import RobotConnectionError, SimulatedUR5e
from histostudy.robot.sim import FaultPlan
from histostudy.treatment import execute_treatment, plan_treatment
from histostudy.treatment.execution import TreatmentRun, UncertainPointError, load_journal
from histostudy.treatment.journal import JournalError


def test_execution_commands_every_point_and_journals_reached_poses(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    plan = plan_treatment(zone, 4.0, pulses_per_point=7, axes=R_CT)
    fired = []
    run = execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.sqlite",
                            deliver=lambda i, n: fired.append((i, n)))
    assert run.completed and run.n_treated == len(plan) and run.resumed_at == 0
    assert fired == [(i, 7) for i in range(len(plan))]
    assert robot.state().moves_completed == len(plan)
    # commanded: the plan points mapped into the base frame, orientation fixed
    assert np.allclose(run.commanded_T_base_tcp[:, :3, 3], transform_points(T_base_carm, plan.points_mm))
    assert np.allclose(run.commanded_T_base_tcp[:, :3, :3], R_base_tcp)
    # reached: within the UR5e repeatability of the commanded position
    err = np.linalg.norm(run.reached_T_base_tcp[:, :3, 3] - run.commanded_T_base_tcp[:, :3, 3], axis=1)
    assert err.max() <= 0.03 + 1e-9 and err.max() > 0
    journal = load_journal(tmp_path / "j.sqlite")
    assert journal["completed"] and len(journal["points"]) == len(plan) and journal["uncertain"] is None
    assert np.allclose(journal["points"][3]["reached_T_base_tcp"], run.reached_T_base_tcp[3])
    assert journal["plan_fingerprint"] == plan.fingerprint()
    # a completed journal makes a rerun do nothing
    robot2 = SimulatedUR5e(2)
    again = execute_treatment(robot2, plan, T_base_carm, R_base_tcp, tmp_path / "j.sqlite")
    assert again.completed and robot2.moves_planned == 0
    assert np.array_equal(again.reached_T_base_tcp, run.reached_T_base_tcp)


@pytest.mark.parametrize("faults, n_journaled", [
    (lambda k: FaultPlan(disconnect_after_moves=k), lambda k: k),  # move k done, then the link drops
    (lambda k: FaultPlan(disconnect_during_move=k), lambda k: k - 1),  # move k never finishes
])
def test_interrupted_treatment_resumes_without_repeating_or_skipping(tmp_path, faults, n_journaled):
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    plan = plan_treatment(zone, 4.0, pulses_per_point=3, axes=R_CT)
    k = 17
    path = tmp_path / "journal.sqlite"
    fired = []
    def deliver(i, n):
        fired.append(i)
    faulty = SimulatedUR5e(1, faults=faults(k))
    with pytest.raises(RobotConnectionError) as info:
        execute_treatment(faulty, plan, T_base_carm, R_base_tcp, path, deliver=deliver)
    assert any("resume" in note for note in getattr(info.value, "__notes__", []))
    # the journal holds exactly the treated points, none uncertain (the fault came before any firing)
    journal = load_journal(path)
    assert [p["index"] for p in journal["points"]] == list(range(n_journaled(k)))
    assert not journal["completed"] and journal["uncertain"] is None
    # the database, its lock and SQLite's WAL files; no temporary file left
    assert {p.name for p in tmp_path.iterdir()} <= {"journal.sqlite", "journal.sqlite.lock", "journal.sqlite-wal",
                                                    "journal.sqlite-shm"}
    before = [p["reached_T_base_tcp"] for p in journal["points"]]
    partial = TreatmentRun.load(path)
    assert partial.n_treated == n_journaled(k) and not partial.completed and partial.n_planned == len(plan)
    # a fresh robot with the same journal treats the rest
    fresh = SimulatedUR5e(2)
    run = execute_treatment(fresh, plan, T_base_carm, R_base_tcp, path, deliver=deliver)
    assert run.completed and run.resumed_at == n_journaled(k)
    assert fresh.state().moves_completed == len(plan) - n_journaled(k)
    assert sorted(fired) == list(range(len(plan))) and len(set(fired)) == len(fired)  # once each
    assert np.array_equal(run.indices, np.arange(len(plan)))
    assert np.allclose(run.reached_T_base_tcp[: len(before)], np.array(before))  # history kept
    err = np.linalg.norm(run.reached_T_base_tcp[:, :3, 3] - run.commanded_T_base_tcp[:, :3, 3], axis=1)
    assert err.max() <= 0.03 + 1e-9


def _stopped_while_firing(tmp_path, index):
    """A treatment whose therapy system faults while firing point ``index`` (some of its pulses may
    have gone out); returns the plan, the calibration, the journal, the firings and the error."""
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    plan = plan_treatment(zone, 5.0, axes=R_CT)
    path, fired = tmp_path / "j.sqlite", []

    def therapy_fault(i, n):
        fired.append(i)
        if i == index:
            raise RuntimeError("generator fault")

    with pytest.raises(RuntimeError, match="generator fault") as info:
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, path, deliver=therapy_fault)
    return plan, T_base_carm, R_base_tcp, path, fired, info.value


def test_a_fault_while_firing_leaves_the_point_uncertain_and_a_resume_refuses_until_told(tmp_path):
    plan, T_base_carm, R_base_tcp, path, fired, error = _stopped_while_firing(tmp_path, 4)
    assert any("may have been fired" in note for note in error.__notes__)
    assert load_journal(path)["uncertain"] == 4 and TreatmentRun.load(path).uncertain == 4
    fresh = SimulatedUR5e(3)
    with pytest.raises(UncertainPointError, match="point 4") as refused:  # the default: never fire twice
        execute_treatment(fresh, plan, T_base_carm, R_base_tcp, path, deliver=fired.append)
    assert refused.value.index == 4 and fresh.moves_planned == 0
    asked = []
    run = execute_treatment(fresh, plan, T_base_carm, R_base_tcp, path, deliver=lambda i, n: fired.append(i),
                            on_uncertain=lambda i: asked.append(i) or "refire")
    assert asked == [4] and run.completed and run.refired == (4,) and run.skipped == ()
    assert sorted(fired) == sorted(list(range(len(plan))) + [4])  # 4 twice, and the journal says so


def test_skipping_an_uncertain_point_fires_it_no_more_and_is_recorded(tmp_path):
    plan, T_base_carm, R_base_tcp, path, fired, _ = _stopped_while_firing(tmp_path, 2)
    run = execute_treatment(SimulatedUR5e(4), plan, T_base_carm, R_base_tcp, path, deliver=lambda i, n: fired.append(i),
                            on_uncertain="skip")
    assert run.completed and run.skipped == (2,) and run.pulses[2] == 0 and sorted(fired) == list(range(len(plan)))
    with pytest.raises(ValueError, match="on_uncertain"):
        execute_treatment(SimulatedUR5e(5), plan, T_base_carm, R_base_tcp, tmp_path / "k.sqlite", on_uncertain="ask")


def test_journal_refuses_another_plan_or_calibration(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    plan = plan_treatment(zone, 5.0, axes=R_CT)
    path = tmp_path / "j.sqlite"
    with pytest.raises(RobotConnectionError):
        execute_treatment(SimulatedUR5e(1, faults=FaultPlan(disconnect_after_moves=3)), plan, T_base_carm, R_base_tcp,
                          path)
    other = plan_treatment(zone, 4.0, axes=R_CT)
    with pytest.raises(ValueError, match="another plan"):
        execute_treatment(robot, other, T_base_carm, R_base_tcp, path)
    shifted = T_base_carm.copy()
    shifted[0, 3] += 1.0
    with pytest.raises(ValueError, match="T_base_carm"):
        execute_treatment(robot, plan, shifted, R_base_tcp, path)
    assert robot.moves_planned == 0  # refused before moving
    (tmp_path / "bad.json").write_text('{"format": "histostudy.treatment_journal", "points": [')
    with pytest.raises(JournalError, match="neither SQLite nor valid JSON"):
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "bad.json")


def test_execution_rejects_bad_arguments(tmp_path):
    robot, zone, T_base_carm, R_base_tcp = robot_zone_and_calibration()
    plan = plan_treatment(zone, 5.0)
    with pytest.raises(ValueError, match="T_base_carm"):
        execute_treatment(robot, plan, np.eye(3), R_base_tcp, tmp_path / "j.json")
    with pytest.raises(ValueError, match="R_base_tcp"):
        execute_treatment(robot, plan, T_base_carm, 2 * np.eye(3), tmp_path / "j.json")
    with pytest.raises(ValueError, match="speed_mm_s"):
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "j.json", speed_mm_s=0.0)
    assert not (tmp_path / "j.json").exists()
