"""Tests of histostudy.pose.options: PoseConfig holds estimate_pose's options with today's defaults,
validates each field, and gives the same pose as the keyword arguments it stands for."""

import dataclasses

import numpy as np
import pytest
from pose_frames import POSES, frames_of

from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import PoseConfig, apply_left_perturbation, estimate_pose
from histostudy.transducer import Feature, TransducerModel

ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


@pytest.fixture(scope="module")
def warm_start(model):
    """Frames of POSES[1] and a start near it: the refinement alone runs (no initialisation)."""
    T = POSES[1]
    return frames_of(model, T), apply_left_perturbation(T, [0.01, -0.01, 0.005, 1.0, -0.8, 0.5])


def test_defaults_are_those_of_the_keyword_arguments():
    o = PoseConfig()
    assert (o.mode, o.init, o.distance_maps) == ("paper", "robust", "occlusion_aware")
    assert o.class_weights is None and o.outside_distance_px == 0.1  # the paper's constant (§II-B.3)
    assert (o.search_truncation_px, o.coarse_truncation_px, o.init_points_per_class) == (30.0, 150.0, 1500)
    assert o.search_centre_mm == (0.0, 0.0, 0.0)
    assert (o.max_rms_px, o.min_inside_fraction, o.direction_spread_limit_deg) == (6.0, 0.02, 15.0)
    assert (o.refine_truncation_px, o.verdict_truncation_px) == (1.0, 10.0)
    assert (o.max_view_disagreement_mm, o.max_body_rms_px, o.max_unexplained_fraction) == (1.5, 1.0, 0.1)
    assert o.raise_on_failure and o.retry_hypotheses and o.largest_component
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.mode = "fast"


def test_options_and_keywords_give_the_same_pose(model, warm_start):
    frames, start = warm_start
    common = dict(rng=np.random.default_rng(3), initial_pose=start, **ORACLES)
    by_keywords = estimate_pose(frames, model, mode="fast", refine_truncation_px=3.0, **common)
    common["rng"] = np.random.default_rng(3)
    by_options = estimate_pose(frames, model, options=PoseConfig(mode="fast", refine_truncation_px=3.0), **common)
    common["rng"] = np.random.default_rng(3)
    # A keyword overrides the corresponding field of ``options``.
    overridden = estimate_pose(frames, model, options=PoseConfig(mode="paper", refine_truncation_px=3.0),
                               mode="fast", **common)
    for other in (by_options, overridden):
        np.testing.assert_array_equal(other.T_carm_transducer, by_keywords.T_carm_transducer)
        assert other.cost == by_keywords.cost and other.mode == "fast"
        assert other.verdict.rms_distance_px == by_keywords.verdict.rms_distance_px


@pytest.mark.parametrize("field, value", [
    ("mode", "slow"), ("init", "random"), ("distance_maps", "chamfer"), ("class_weights", [1.0]),
    ("class_weights", {Feature.GAPS: -1.0}), ("outside_distance_px", -0.1), ("outside_distance_px", np.inf),
    ("search_truncation_px", 0.0), ("coarse_truncation_px", "150"), ("init_points_per_class", 0),
    ("init_points_per_class", 2.5), ("search_centre_mm", (0.0, 1.0)), ("search_centre_mm", (0.0, np.nan, 0.0)),
    ("max_rms_px", 0.0), ("min_inside_fraction", 1.5), ("raise_on_failure", "yes"), ("retry_hypotheses", None),
    ("largest_component", 2), ("direction_spread_limit_deg", 0), ("direction_spread_limit_deg", 181.0),
    ("refine_truncation_px", -1.0), ("verdict_truncation_px", np.inf), ("max_view_disagreement_mm", 0.0),
    ("max_body_rms_px", True), ("max_unexplained_fraction", "0.1"),
])
def test_a_bad_value_raises_a_value_error_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        PoseConfig(**{field: value})


def test_bad_keywords_and_options_raise_before_any_work(model, warm_start):
    frames, _ = warm_start
    with pytest.raises(TypeError, match="unexpected keyword argument 'refine_truncation'"):
        estimate_pose(frames, model, refine_truncation=1.0, **ORACLES)
    with pytest.raises(TypeError, match="options must be a histostudy.pose.PoseConfig"):
        estimate_pose(frames, model, options={"mode": "fast"}, **ORACLES)
    with pytest.raises(ValueError, match="max_rms_px must be a number > 0"):
        estimate_pose(frames, model, options=PoseConfig(mode="fast"), max_rms_px=-1.0, **ORACLES)


def test_values_are_normalised_without_changing_them():
    weights = {Feature.GAPS: 2.0}
    o = PoseConfig(search_centre_mm=np.array([1, 2, 3]), class_weights=weights)
    assert o.search_centre_mm == (1.0, 2.0, 3.0)
    weights[Feature.GAPS] = 5.0  # a later edit of the caller's dict does not reach the frozen record
    assert dict(o.class_weights) == {Feature.GAPS: 2.0}
