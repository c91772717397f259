"""Tests of histostudy.study.pose._robustness: the initialisation sweep over random poses and its summary."""

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane
from histostudy.study import pose as study
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.transducer import TransducerModel


class CountingSegmenter:
    """Perfect labels (the oracle without degradation draws nothing), counting the calls; says it
    draws nothing only when told (``uses_rng``)."""

    def __init__(self, uses_rng: bool = True):
        self.calls, self.uses_rng = 0, uses_rng

    def segment(self, frame, rng=None):
        from histostudy.learning import OracleSegmenter

        self.calls += 1
        return OracleSegmenter().segment(frame, rng)


@pytest.mark.slow
def test_robustness_sweep_runs_the_stages_it_is_given():
    from histostudy.learning import OracleOrientation

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    segmenter = CountingSegmenter()
    table = study.robustness_sweep(1, pose_model=model, render_model=model, physical=physical,
                                   views=default_biplane(), seed=5, config=PoseStudyConfig(n_splats=1),
                                   inits=("robust",), segmenter=segmenter, orientation=OracleOrientation())
    assert segmenter.calls == 2 and list(table["init"]) == ["robust"]
    assert table["success"].all() and table["error_mm"].iloc[0] < 1.0
    # the digital model looks the same after a half turn: the rotation error is taken up to it
    assert table["rotation_error_deg"].iloc[0] < 2.0 and table["half_turned"].dtype == bool


@pytest.mark.slow
def test_stage_sets_on_each_pose_s_frames_give_the_rows_of_a_sweep_per_set():
    from histostudy.learning import OracleOrientation

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    kwargs = dict(pose_model=model, render_model=model, physical=physical, views=default_biplane(), seed=7,
                  config=PoseStudyConfig(n_splats=1, splat_device="cpu"))
    perfect = CountingSegmenter(uses_rng=False)
    sets = {"oracle": dict(inits=("robust",)),  # the Table I oracle: draws its degradations
            "perfect": dict(inits=("robust",), segmenter=perfect, orientation=OracleOrientation()),
            "perfect, paper init": dict(inits=("paper",), segmenter=perfect)}
    together = study.robustness_sweep(2, **kwargs, stage_sets=sets)
    assert perfect.calls == 2 * 2  # each pose's two frames once, for both sets that share the segmenter
    separate = pd.concat([study.robustness_sweep(2, **kwargs, **given).assign(stages=name)
                          for name, given in sets.items()], ignore_index=True)
    together = together.sort_values("stages", key=lambda s: s.map(list(sets).index), kind="stable", ignore_index=True)
    pd.testing.assert_frame_equal(together.drop(columns="seconds"), separate.drop(columns="seconds"), check_exact=True)
    with pytest.raises(ValueError, match="stage_sets must map names to dicts"):
        study.robustness_sweep(1, **kwargs, stage_sets={"x": {"segmentor": perfect}})


def test_robustness_summary_counts_refusals_and_wrong_accepted_poses():
    robust = pd.DataFrame({
        "pose": [0, 1, 2, 3, 0, 1], "init": ["robust"] * 4 + ["paper"] * 2,
        "verdict_ok": [True, True, False, True, True, False], "success": [True, False, False, True, True, False],
        "error_mm": [0.5, 41.0, np.nan, 0.3, 0.7, np.nan], "seconds": [1.0, 3.0, 4.0, 2.0, 1.0, 5.0]})
    summary = study.robustness_summary(robust).set_index("init")
    assert summary.loc["robust", "poses"] == 4 and summary.loc["robust", "success_rate"] == 0.5
    assert summary.loc["robust", "refused"] == 1 and summary.loc["robust", "wrong_accepted"] == 1
    assert summary.loc["robust", "median_error_mm"] == 0.5 and summary.loc["robust", "median_seconds"] == 2.5
    assert (summary.loc["paper", "refused"], summary.loc["paper", "wrong_accepted"]) == (1, 0)
    with pytest.raises(ValueError, match=r"missing columns \['verdict_ok'\]"):
        study.robustness_summary(robust.drop(columns="verdict_ok"))


@pytest.mark.slow
def test_robustness_sweep_gives_the_same_rows_in_process_or_on_a_local_cluster():
    from histostudy.learning import OracleOrientation

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    kwargs = dict(pose_model=model, render_model=model, physical=physical, views=default_biplane(), seed=11,
                  config=PoseStudyConfig(n_splats=1), inits=("robust",), orientation=OracleOrientation())
    one = study.robustness_sweep(2, **kwargs)
    two = study.robustness_sweep(2, workers=2, **kwargs)  # a dask LocalCluster of 2 worker processes
    pd.testing.assert_frame_equal(one.drop(columns="seconds"), two.drop(columns="seconds"), check_exact=True)
    assert {"rms_A", "body_rms_B", "unexplained_A", "disagreement_mm_B", "gain_px2_A",
            "relative_gain_B"} <= set(one.columns)
    assert one["verdict_ok"].all() and (one["error_mm"] < 2.0).all()
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        study.robustness_sweep(2, workers=0, **kwargs)


def test_robustness_sweep_refuses_a_bad_executor_before_any_work(monkeypatch):
    model = TransducerModel.build(spacing_mm=2.0)
    kwargs = dict(pose_model=model, render_model=model, physical=model, views=default_biplane(), seed=11,
                  config=PoseStudyConfig(n_splats=1))
    with pytest.raises(ValueError, match="give workers or executor, not both"):
        study.robustness_sweep(2, workers=2, executor="local", **kwargs)
    with pytest.raises(ValueError, match="executor must be 'sequential', 'local'"):
        study.robustness_sweep(2, executor="threads", **kwargs)
    monkeypatch.setenv("HISTOSTUDY_SCHEDULER", "tcp://nowhere")
    with pytest.raises(ValueError, match="HISTOSTUDY_SCHEDULER must be a scheduler address"):
        study.robustness_sweep(2, **kwargs)
