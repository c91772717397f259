"""Tests of histostudy.core.stage_profile on a clock the test steps: exclusive nesting, the same stage
inside itself, a bad name, threads, decorators, snapshots, their difference and merged totals."""

import threading
import time

import pytest

from histostudy.core import STAGES, merge_stage_totals, stage, stage_delta, stage_totals


def charged(before):
    # rounded: the totals hold what the process charged before the test, so a difference of them
    # carries their float rounding
    return {name: (round(t["wall_s"], 9), round(t["cpu_s"], 9), t["calls"]) for name, t in stage_delta(before).items()}


def test_a_stage_inside_another_pauses_it(stage_clock):
    before = stage_totals()
    with stage("pose"):
        stage_clock.tick(1.0, 2.0)
        with stage("render"):  # a render inside a pose estimate is charged to render
            stage_clock.tick(4.0, 8.0)
        stage_clock.tick(2.0, 1.0)
        with stage("segment"):
            stage_clock.tick(0.5)
            with stage("orient"):
                stage_clock.tick(0.25)
            stage_clock.tick(0.5)
    stage_clock.tick(9.0)  # outside every stage: charged to none
    assert charged(before) == {"render": (4.0, 8.0, 1), "segment": (1.0, 1.0, 1), "orient": (0.25, 0.25, 1),
                               "pose": (3.0, 3.0, 1)}


def test_the_same_stage_inside_itself_counts_once(stage_clock):
    before = stage_totals()
    with stage("render"):
        stage_clock.tick(1.0)
        with stage("render"):
            stage_clock.tick(2.0)
            with stage("render"):
                stage_clock.tick(3.0)
        stage_clock.tick(1.0)
    assert charged(before) == {"render": (7.0, 7.0, 1)}
    # deeper down the stack too: a render inside a pose inside a render is the outer render's call
    before = stage_totals()
    with stage("render"):
        stage_clock.tick(1.0)
        with stage("pose"):
            stage_clock.tick(2.0)
            with stage("render"):
                stage_clock.tick(4.0)
            stage_clock.tick(2.0)
    assert charged(before) == {"render": (5.0, 5.0, 1), "pose": (4.0, 4.0, 1)}


def test_a_decorated_function_is_charged_per_call_and_still_raises(stage_clock):
    @stage("statistics")
    def mean(values):
        """The mean."""
        stage_clock.tick(0.5)
        if not values:
            raise ValueError("no values")
        return sum(values) / len(values)

    before = stage_totals()
    assert mean([1, 2, 3]) == 2 and mean.__doc__ == "The mean." and mean.__name__ == "mean"
    with pytest.raises(ValueError, match="no values"):
        mean([])
    assert charged(before) == {"statistics": (1.0, 1.0, 2)}  # the failed call is charged too


def test_a_bad_stage_name_is_refused_with_the_allowed_names():
    with pytest.raises(ValueError, match=r"name must be one of \('render', .*'report'\), got 'rendering'"):
        stage("rendering")
    with pytest.raises(ValueError, match="got None"):
        stage(None)
    with pytest.raises(ValueError, match="got \\['pose'\\]"):
        stage(["pose"])
    assert STAGES == ("render", "segment", "orient", "pose", "calibrate", "statistics", "report")


def test_each_thread_keeps_its_own_open_stages(stage_clock):
    """A thread's stage does not pause another thread's: both are charged the (process-wide) clock
    over their own blocks."""
    entered, release = threading.Event(), threading.Event()

    def worker():
        with stage("segment"):
            entered.set()
            release.wait()

    before = stage_totals()
    with stage("pose"):
        thread = threading.Thread(target=worker)
        thread.start()
        entered.wait()
        stage_clock.tick(3.0)
        release.set()
        thread.join()
        stage_clock.tick(1.0)
    assert charged(before) == {"segment": (3.0, 3.0, 1), "pose": (4.0, 4.0, 1)}


def test_blocks_closed_out_of_order_are_still_charged(stage_clock):
    """A generator suspended inside a stage closes it after its caller's stage opened."""
    def frames():
        with stage("render"):
            stage_clock.tick(1.0)
            yield 1
            stage_clock.tick(2.0)

    before = stage_totals()
    source = frames()
    next(source)
    with stage("pose"):
        stage_clock.tick(4.0)
        source.close()  # the render closes while pose is the innermost stage
        stage_clock.tick(8.0)
    assert charged(before) == {"render": (1.0, 1.0, 1), "pose": (12.0, 12.0, 1)}


def test_delta_and_merge(stage_clock):
    before = stage_totals()
    with stage("calibrate"):
        stage_clock.tick(2.0, 1.0)
    delta = stage_delta(before)
    assert delta == {"calibrate": {"wall_s": pytest.approx(2.0), "cpu_s": pytest.approx(1.0), "calls": 1}}
    assert stage_delta(stage_totals(), stage_totals()) == {}
    assert stage_delta({}, {"pose": {"wall_s": 1, "cpu_s": 2, "calls": 3}}) == {
        "pose": {"wall_s": 1.0, "cpu_s": 2.0, "calls": 3}}

    # a worker's totals added to this process's: snapshots include them
    middle = stage_totals()
    merge_stage_totals({"render": {"wall_s": 5.0, "cpu_s": 6.0, "calls": 7}, "calibrate": delta["calibrate"]})
    assert charged(middle) == {"render": (5.0, 6.0, 7), "calibrate": (2.0, 1.0, 1)}
    assert list(stage_delta(before)) == ["render", "calibrate"]  # in the order of STAGES
    with pytest.raises(ValueError, match="delta names the stage 'plotting'"):
        merge_stage_totals({"plotting": {"wall_s": 1.0, "cpu_s": 1.0, "calls": 1}})
    with pytest.raises(ValueError, match=r"delta\['pose'\] must hold"):
        merge_stage_totals({"pose": {"wall_s": 1.0}})
    with pytest.raises(ValueError, match="before must be a mapping"):
        stage_delta([1, 2])
    assert charged(middle) == {"render": (5.0, 6.0, 7), "calibrate": (2.0, 1.0, 1)}  # nothing of the refused


def test_a_snapshot_is_a_copy(stage_clock):
    with stage("report"):
        stage_clock.tick(1.0)
    snapshot = stage_totals()
    calls = snapshot["report"]["calls"]
    snapshot["report"]["calls"] += 100
    snapshot.pop("report")
    assert stage_totals()["report"]["calls"] == calls


def test_cpu_seconds_counts_this_process_and_its_finished_children():
    import subprocess
    import sys

    from histostudy.core import cpu_seconds

    own0, children0 = cpu_seconds(children=False), cpu_seconds(own=False)
    t_end = time.process_time() + 0.2
    while time.process_time() < t_end:  # 0.2 CPU-s of this process
        pass
    assert cpu_seconds(children=False) - own0 >= 0.19
    assert cpu_seconds(own=False) == children0  # no child finished meanwhile
    busy = "import time\nt = time.process_time() + 0.3\nwhile time.process_time() < t: pass"
    subprocess.run([sys.executable, "-c", busy], check=True)
    assert cpu_seconds(own=False) - children0 >= 0.3
    assert cpu_seconds(own=False, children=False) == 0.0
