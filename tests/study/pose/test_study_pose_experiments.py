"""Tests of histostudy.study.pose._experiments: the experiments' draws and one small experiment end to end."""

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane, random_background
from histostudy.study.pose.experiments import PoseStudyConfig, experiment_setups, run_pose_study
from histostudy.study.pose.geometry import experiment_pose, margin_positions
from histostudy.study.pose.metrics import experiment_metrics, stage_timing, tracking_summary
from histostudy.transducer import TransducerModel


@pytest.mark.slow
def test_one_small_experiment_end_to_end():
    """Coarse rendering (0.47 mm, 2 splats) and the fast mode: every position estimated, errors
    well inside a millimetre, and the metrics computed from the rows."""
    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    config = PoseStudyConfig(n_experiments=1, modes=("fast",), n_splats=2, track=True)
    records = run_pose_study(config, pose_model=model, render_model=model, physical=physical,
                                   views=default_biplane(), seed=11)
    full = records[records["mode"] == "fast"]
    assert len(full) == 7 and set(records["mode"]) == {"fast", "track"}
    assert full["ok"].all(), full["failure"].tolist()
    assert full["err_euclidean"].max() < 1.0, full["err_euclidean"].tolist()
    metrics = experiment_metrics(records)
    assert len(metrics) == 1 and metrics["radius_err_overall"].iloc[0] < 0.5
    summary = tracking_summary(records)
    assert summary["n"] == 6 and summary["track_error_mm"][0] < 1.0
    timing = stage_timing(records)
    assert set(timing["mode"]) == {"fast", "track"} and (timing["total"] > 0).all()


def test_experiment_setups_keep_the_study_draws():
    """Drawing the CBCT stream (child 5) changes none of run_pose_study's draws (children 0-4)."""
    config = PoseStudyConfig(n_experiments=2)
    setups = experiment_setups(config, 7)
    assert [s.experiment for s in setups] == [0, 1]
    for exp, seq in zip(setups, np.random.SeedSequence(7).spawn(2)):
        rng_pose, rng_scene, _, rng_robot, _ = (np.random.default_rng(s) for s in seq.spawn(5))
        radius = float(rng_pose.choice(config.margin_mm))
        scene = random_background(rng_scene, config.background)
        T_centre = experiment_pose(rng_pose, config, scene.meta["phantom_center_mm"])
        assert exp.radius_mm == radius
        np.testing.assert_array_equal(exp.T_centre, T_centre)
        for position, T_nominal in margin_positions(T_centre, radius).items():
            expected = T_nominal.copy()
            expected[:3, 3] += rng_robot.normal(0, config.robot_repeatability_mm, 3)
            np.testing.assert_array_equal(exp.T_true[position], expected)


class _CountingSegmenter:
    """Perfect labels (the oracle without degradation draws nothing), counting the calls."""

    def __init__(self, uses_rng: bool):
        from histostudy.learning import OracleSegmenter

        self.oracle, self.uses_rng, self.calls = OracleSegmenter(None), uses_rng, 0

    def segment(self, frame, rng=None):
        self.calls += 1
        return self.oracle.segment(frame, rng)


@pytest.mark.slow
def test_a_segmenter_that_draws_nothing_segments_each_acquisition_once_with_the_same_rows():
    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    config = PoseStudyConfig(n_experiments=1, modes=("fast",), n_splats=2, track=True, splat_device="cpu")
    runs = {}
    for uses_rng in (True, False):
        segmenter = _CountingSegmenter(uses_rng)
        records = run_pose_study(config, pose_model=model, render_model=model, physical=physical,
                                 views=default_biplane(), seed=11, segmenter=segmenter)
        runs[uses_rng] = (records.drop(columns=[c for c in records if c.startswith("s_")]), segmenter.calls)
    (every_time, calls_every_time), (once, calls_once) = runs[True], runs[False]
    assert calls_every_time == 2 * len(every_time) == 2 * (7 + 6)  # two views per estimate: 7 fast + 6 tracks
    assert calls_once == 2 * 7  # two views per acquisition
    pd.testing.assert_frame_equal(once, every_time)
