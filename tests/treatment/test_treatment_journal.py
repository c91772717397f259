"""Fault tests of histostudy.treatment.journal: one writer at a time, SIGKILLs anywhere, tampered
and old journals. The truth a run is checked against is the therapy system's own log of firings
(tests/treatment/treatment_faults.py), written by the child processes the tests kill."""

import json
import multiprocessing
import os
import sqlite3
import time
from collections import Counter

import numpy as np
import pytest
from treatment_faults import fault_plan, fired_points, treat

from histostudy.robot import SimulatedUR5e
from histostudy.treatment import execute_treatment
from histostudy.treatment.execution import TreatmentRun, load_journal
from histostudy.treatment.journal import JournalError, JournalLockedError, TreatmentJournal


@pytest.fixture(scope="module")
def forkserver():
    """Children forked from a clean server that has imported the treatment code once (fast, and
    safe beside this process's threads)."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["histostudy.treatment", "histostudy.robot", "treatment_faults"])
    return ctx


def _wait_for(predicate, timeout_s=30.0):
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError("the child process did not get there in time")
        time.sleep(0.005)


def _calibration(T_base_carm, R_base_tcp):
    return {"T_base_carm": T_base_carm, "R_base_tcp": R_base_tcp, "T_flange_tcp": None}


def test_a_second_run_on_a_held_journal_is_refused_before_the_robot_moves(tmp_path, forkserver):
    journal, fired = tmp_path / "j.sqlite", tmp_path / "fired.log"
    first = forkserver.Process(target=treat, args=(journal, fired, 1), kwargs={"fire_s": 0.004})
    first.start()
    try:
        _wait_for(lambda: len(fired_points(fired)) >= 3)
        plan, T_base_carm, R_base_tcp = fault_plan()
        robot = SimulatedUR5e(2)
        with pytest.raises(JournalLockedError, match=rf"in use by pid {first.pid} on "):
            execute_treatment(robot, plan, T_base_carm, R_base_tcp, journal, deliver=lambda i, n: None)
        assert robot.moves_planned == 0 and robot.state().moves_completed == 0
    finally:
        first.join(120)
    assert first.exitcode == 0
    counts = Counter(fired_points(fired))
    assert sorted(counts) == list(range(len(plan))) and set(counts.values()) == {1}  # 0 fired twice
    # the lock went with its holder: the journal opens again, complete
    assert execute_treatment(SimulatedUR5e(3), plan, T_base_carm, R_base_tcp, journal).completed


def test_two_processes_started_together_fire_each_point_once(tmp_path, forkserver):
    journal, fired = tmp_path / "j.sqlite", tmp_path / "fired.log"
    runs = [forkserver.Process(target=treat, args=(journal, fired, seed), kwargs={"fire_s": 0.0, "spacing_mm": 5.0})
            for seed in (1, 2)]
    for run in runs:
        run.start()
    for run in runs:
        run.join(120)
    # one of them held the journal; the other was refused at once (or found it complete)
    assert 0 in [run.exitcode for run in runs]
    counts = Counter(fired_points(fired))
    assert set(counts.values()) == {1} and len(counts) == len(fault_plan(5.0)[0])


def test_fifty_random_sigkills_skip_nothing_and_refire_nothing_silently(tmp_path, forkserver):
    """Kill the treating process 50 times at random moments, resume after each. The journal's
    uncertain points (an intent, no done) are settled from the therapy system's log; in the end
    every plan point has fired exactly once, and every uncertain point is listed in the run."""
    journal, fired = tmp_path / "j.sqlite", tmp_path / "fired.log"
    plan, T_base_carm, R_base_tcp = fault_plan()
    rng = np.random.default_rng(20)
    uncertain_after_kill = []
    for kill in range(50):
        fired_before = len(fired_points(fired))
        child = forkserver.Process(target=treat, args=(journal, fired, kill))
        child.start()
        # kill while it treats: after its first new firing, at a random moment of the next ~3 points
        _wait_for(lambda n=fired_before, c=child: len(fired_points(fired)) > n or not c.is_alive())
        time.sleep(rng.uniform(0.0, 0.04))
        child.kill()  # SIGKILL: no handler, no cleanup
        child.join()
        if journal.exists():
            with TreatmentJournal.open_for_reading(journal) as state:
                if state.uncertain is not None:
                    uncertain_after_kill.append(state.uncertain)
    final = forkserver.Process(target=treat, args=(journal, fired, 99))
    final.start()
    final.join(300)
    assert final.exitcode == 0
    run = TreatmentRun.load(journal)
    counts = Counter(fired_points(fired))
    assert run.completed and np.array_equal(run.indices, np.arange(len(plan)))
    assert sorted(counts) == list(range(len(plan)))  # 0 skipped
    assert [i for i, n in counts.items() if n != 1] == []  # 0 fired twice
    settled = set(run.refired) | set(run.skipped)
    assert set(uncertain_after_kill) <= settled  # every uncertain point listed in the run
    assert len(set(uncertain_after_kill)) >= 5  # the kills did land inside firings (fire_s is most of a point)
    print(f"50 SIGKILLs, {len(plan)} points: {len(set(uncertain_after_kill))} uncertain after a kill, "
          f"{len(run.skipped)} settled as fired, {len(run.refired)} re-fired because they had not fired")


def _finished_journal(tmp_path, name="j.sqlite", stop_after=None):
    plan, T_base_carm, R_base_tcp = fault_plan(5.0)
    path = tmp_path / name
    robot = SimulatedUR5e(1)
    if stop_after is not None:
        from histostudy.robot import RobotConnectionError
        from histostudy.robot.sim import FaultPlan

        with pytest.raises(RobotConnectionError):
            execute_treatment(SimulatedUR5e(1, faults=FaultPlan(disconnect_after_moves=stop_after)), plan,
                              T_base_carm, R_base_tcp, path)
    else:
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, path)
    return path, plan, T_base_carm, R_base_tcp


def _tamper(path, *statements):
    db = sqlite3.connect(path)
    for sql in statements:
        db.execute(sql)
    db.commit()
    db.close()


@pytest.mark.parametrize("statements, match", [
    (["DELETE FROM points WHERE idx = 3"], "not the plan's first points"),  # a record missing
    (["DELETE FROM points WHERE idx = 9", "UPDATE meta SET value = '9' WHERE key = 'n_finished'"], None),  # truncated
    (["INSERT INTO points VALUES (200, '[0,0,0]', '[]', '[]', 't', 't', 5, NULL)"], "holds point 200|first points"),
    (["UPDATE meta SET value = (SELECT value FROM meta WHERE key = 'n_planned') WHERE key = 'n_finished'"],
     "counts 81 finished points but holds 10"),  # "completed" faked
    (["UPDATE points SET done_utc = NULL WHERE idx = 2"], "not the plan's first points"),  # a done erased
    (["UPDATE points SET done_utc = NULL WHERE idx = 9", "UPDATE meta SET value = '9' WHERE key = 'n_finished'",
      "INSERT INTO points VALUES (10, '[0,0,0]', '[]', '[]', 't', NULL, NULL, NULL)"], "only the point after"),
    (["UPDATE meta SET value = replace(value, '5', '6') WHERE key = 'plan'"], "fingerprint"),  # plan edited
    (["UPDATE meta SET value = '3' WHERE key = 'version'"], "version"),
])
def test_tampered_journals_are_refused_before_the_robot_moves(tmp_path, statements, match):
    path, plan, T_base_carm, R_base_tcp = _finished_journal(tmp_path, stop_after=10)
    _tamper(path, *statements)
    robot = SimulatedUR5e(2)
    if match is None:  # a consistent truncation by hand cannot be told from a shorter run: it resumes there
        run = execute_treatment(robot, plan, T_base_carm, R_base_tcp, path)
        assert run.resumed_at == 9 and run.completed
        return
    with pytest.raises(JournalError, match=match):
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, path)
    assert robot.moves_planned == 0


def test_a_journal_is_refused_for_another_plan_or_calibration(tmp_path):
    path, plan, T_base_carm, R_base_tcp = _finished_journal(tmp_path, stop_after=4)
    other = fault_plan(4.0)[0]
    with pytest.raises(JournalError, match="another plan"):
        execute_treatment(SimulatedUR5e(2), other, T_base_carm, R_base_tcp, path)
    with pytest.raises(JournalError, match="R_base_tcp"):
        execute_treatment(SimulatedUR5e(2), plan, T_base_carm, R_base_tcp @ np.diag([1.0, -1.0, -1.0]), path)
    (tmp_path / "noise.sqlite").write_bytes(b"SQLite format 3\x00" + os.urandom(200))
    with pytest.raises(JournalError, match="not a readable treatment journal"):
        execute_treatment(SimulatedUR5e(2), plan, T_base_carm, R_base_tcp, tmp_path / "noise.sqlite")


def _as_v1(journal: dict) -> dict:
    """A version-1 (JSON) journal of the same run, as execute_treatment wrote them before SQLite."""
    points = [{k: p[k] for k in ("index", "point_carm_mm", "commanded_T_base_tcp", "reached_T_base_tcp", "pulses")}
              for p in journal["points"]]
    return {"format": journal["format"], "version": 1, "plan_fingerprint": journal["plan_fingerprint"],
            "plan": journal["plan"], "T_base_carm": journal["T_base_carm"], "R_base_tcp": journal["R_base_tcp"],
            "T_flange_tcp": journal["T_flange_tcp"], "completed": journal["completed"], "points": points}


def test_a_version_1_json_journal_is_migrated_and_resumed(tmp_path):
    path, plan, T_base_carm, R_base_tcp = _finished_journal(tmp_path, stop_after=10)
    old = tmp_path / "old.json"
    old.write_text(json.dumps(_as_v1(load_journal(path))))
    fired = []
    run = execute_treatment(SimulatedUR5e(5), plan, T_base_carm, R_base_tcp, old, deliver=lambda i, n: fired.append(i))
    assert run.resumed_at == 10 and run.completed and fired == list(range(10, len(plan)))
    assert load_journal(old)["version"] == 2 and (tmp_path / "old.json.v1.json").exists()  # the JSON kept


@pytest.mark.parametrize("edit, match", [
    (lambda j: j.update(completed=True), "completed=True with 10 of"),  # 113 points would be skipped
    (lambda j: j["points"].extend(j["points"]), "not the first points"),  # duplicates
    (lambda j: j["points"].extend({**j["points"][0], "index": i} for i in range(10, 200)), "first points"),
    (lambda j: j["points"][3].pop("reached_T_base_tcp"), "every point must hold"),
    (lambda j: j.pop("plan"), "lacks"),
    (lambda j: j.update(format="something else"), "not a treatment journal"),
])
def test_tampered_version_1_journals_are_refused_with_a_clear_error(tmp_path, edit, match):
    path, plan, T_base_carm, R_base_tcp = _finished_journal(tmp_path, stop_after=10)
    old = _as_v1(load_journal(path))
    edit(old)
    (tmp_path / "old.json").write_text(json.dumps(old))
    robot = SimulatedUR5e(2)
    with pytest.raises(JournalError, match=match):
        execute_treatment(robot, plan, T_base_carm, R_base_tcp, tmp_path / "old.json")
    assert robot.moves_planned == 0
    with pytest.raises(JournalError, match=match):
        load_journal(tmp_path / "old.json")


def test_the_journal_file_honours_the_umask(tmp_path):
    import stat

    old = os.umask(0o022)
    try:
        path, *_ = _finished_journal(tmp_path)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
