"""Notebook 04's projector comparison: the same poses, scenes and estimation streams on both projectors."""

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.study.pose._projectors import comparison_poses, projector_comparison, projector_summary
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.transducer import TransducerModel


def test_comparison_poses_are_the_study_centres_then_random_poses_in_view():
    views = [v.scaled(0.25) for v in default_biplane()]
    model = TransducerModel.build(spacing_mm=2.0)
    poses = comparison_poses(PoseStudyConfig(), 3, n_study=2, n_random=3, views=views, pose_model=model)
    assert [p["kind"] for p in poses] == ["study"] * 2 + ["random"] * 3
    again = comparison_poses(PoseStudyConfig(), 3, n_study=2, n_random=3, views=views, pose_model=model)
    for a, b in zip(poses, again):
        np.testing.assert_array_equal(a["T"], b["T"])
    for p in poses[2:]:
        for v in views:
            assert v.in_image(v.project(p["T"][:3, 3][None]))[0]
    with pytest.raises(ValueError, match="n_random"):
        comparison_poses(PoseStudyConfig(), 3, n_study=0, n_random=-1, views=views, pose_model=model)


def test_with_oracle_stages_both_projectors_give_the_same_estimate():
    pytest.importorskip("itk")
    from histostudy.imaging import rtk_available

    if not rtk_available():
        pytest.skip("itk-rtk cannot be loaded")
    views = [v.scaled(0.25) for v in default_biplane()]
    pose_model = TransducerModel.build(spacing_mm=1.0)
    render_model = TransducerModel.build(spacing_mm=1.0)
    physical = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0))
    config = PoseStudyConfig(photons_per_pixel=1e4)
    poses = comparison_poses(config, 5, n_study=1, n_random=0, views=views, pose_model=pose_model)
    rows = projector_comparison(poses, pose_model=pose_model, render_model=render_model, physical=physical,
                                views=views, config=config, seed=5, segmenter=OracleSegmenter(),
                                orientation=OracleOrientation(), voxel_mm=1.0)
    assert list(rows["projector"]) == ["splatting", "rtk-joseph"]
    # the oracles read the reference labels and the true pose, never the image: the same estimate
    assert rows["error_mm"].iloc[0] == pytest.approx(rows["error_mm"].iloc[1], abs=1e-9)
    summary = projector_summary(rows)
    assert summary["paired_difference_mm"].iloc[0] == pytest.approx(0.0, abs=1e-9)
    assert set(summary["projector"]) == {"splatting", "rtk-joseph"}


def test_summary_counts_refusals_and_wrong_acceptances():
    rows = pd.DataFrame({"kind": ["random"] * 4, "pose": [0, 0, 1, 1],
                         "projector": ["splatting", "rtk-joseph"] * 2,
                         "error_mm": [0.5, 0.7, 3.0, 0.4], "verdict_ok": [True, True, True, False],
                         "success": [True, True, False, False]})
    s = projector_summary(rows).set_index("projector")
    assert s.loc["splatting", "accepted_wrong"] == 1 and s.loc["rtk-joseph", "refused"] == 1
    assert s.loc["splatting", "mean_error_mm"] == pytest.approx(1.75)
    assert s.loc["rtk-joseph", "paired_difference_mm"] == pytest.approx(0.2)  # pose 0 only: both accepted
