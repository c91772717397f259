"""Tests of histostudy.pose.verdict: the statistics the pose verdict is judged on, at known poses
of exact labels (the verdict's decisions inside estimate_pose: tests/test_pose_estimate.py)."""

import numpy as np
import pytest
from pose_frames import POSES, frames_of

from histostudy.pose import DistanceMaps, PoseCost
from histostudy.pose.verdict import single_view_evidence, unexplained_fraction, view_disagreement_mm
from histostudy.transducer import Feature, TransducerModel


@pytest.fixture(scope="module")
def models():
    return TransducerModel.build(spacing_mm=0.47), TransducerModel.build(spacing_mm=0.25)


@pytest.fixture(scope="module")
def frames(models):
    return [frames_of(models[1], T) for T in POSES]


def test_unexplained_fraction_counts_the_segmented_pixels_far_from_the_posed_model(models, frames):
    T = POSES[0]
    f = frames[0][0]
    assert unexplained_fraction(f.view, f.labels, models[0], T, 10.0) < 0.005
    spurious = f.labels.copy()
    spurious[:100, :100] = Feature.TRANSDUCER  # a corner block far from the transducer
    n_seg = np.count_nonzero(spurious)
    expected = np.count_nonzero(spurious[:100, :100] > 0) / n_seg
    assert abs(unexplained_fraction(f.view, spurious, models[0], T, 10.0) - expected) < 0.005
    assert np.isnan(unexplained_fraction(f.view, np.zeros_like(f.labels), models[0], T, 10.0))


@pytest.mark.parametrize("tolerance_px", [0.0, 1.0, 1.5, 5.0, 7.3, 10.0, 16.0, 20.0])
def test_unexplained_fraction_equals_scipys_exact_distance_transform(models, frames, tolerance_px):
    # Up to 16 px the pixels are found by a dilation with a disk, beyond by OpenCV's distance
    # transform: both must be scipy's exact Euclidean distance thresholded at the tolerance.
    from scipy.ndimage import distance_transform_edt

    T = POSES[0]
    f = frames[0][0]
    labels = f.labels.copy()
    labels[:60, :80] = Feature.TRANSDUCER  # segmented pixels at every distance from the model
    points = np.vstack([p for p in models[0].points.values() if len(p)])
    uvw = f.view.project_homogeneous(points @ T[:3, :3].T + T[:3, 3])
    px = np.round(uvw[:, :2] / uvw[:, 2:3]).astype(int)
    h, w = labels.shape
    px = px[(px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)]
    not_model = np.ones((h, w), bool)
    not_model[px[:, 1], px[:, 0]] = False
    expected = np.mean(distance_transform_edt(not_model)[labels > 0] > tolerance_px)
    assert 0.0 < expected < 1.0
    assert unexplained_fraction(f.view, labels, models[0], T, tolerance_px) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), "5", None])
def test_unexplained_fraction_refuses_a_bad_tolerance(models, frames, bad):
    f = frames[0][0]
    with pytest.raises(ValueError, match="tolerance_px"):
        unexplained_fraction(f.view, f.labels, models[0], POSES[0], bad)


def test_view_disagreement_is_zero_at_the_exact_pose_of_exact_labels(models, frames):
    T = POSES[1]
    maps = [DistanceMaps(f.view, f.labels, occlusion_aware=True) for f in frames[1]]
    cost = PoseCost(models[1].points, maps).capped(1.0)
    moves = view_disagreement_mm(cost, frames[1], T, models[1].focal_point_mm)
    assert set(moves) == {"A", "B"} and max(moves.values()) < 0.05, moves
    # One view alone leaves the depth along its ray free: a pose moved along plane A's ray is
    # still at A's optimum, and the move is not counted.
    a = frames[1][0].view
    along = T.copy()
    along[:3, 3] += 3.0 * a.ray_directions(a.project(T[:3, 3][None]))[0]
    assert view_disagreement_mm(cost.select_views(0), frames[1][:1], along, models[1].focal_point_mm)["A"] < 0.3


def test_single_view_evidence_prices_each_view_move(models, frames):
    T = POSES[1]
    maps = [DistanceMaps(f.view, f.labels, occlusion_aware=True) for f in frames[1]]
    cost = PoseCost(models[1].points, maps).capped(1.0)
    exact = single_view_evidence(cost, frames[1], T, models[1].focal_point_mm)
    for name, e in exact.items():
        assert e.gain_px2 <= 0.05 * max(e.cost_px2, 1e-3), (name, e)
    # Across plane A's ray, 1.5 mm off: view A's own optimum brings the focal point back, and the
    # move costs view A what it gains over the pose moved.
    a = frames[1][0].view
    ray = a.ray_directions(a.project(T[:3, 3][None]))[0]
    across = np.cross(ray, [0.0, 0.0, 1.0])
    moved = T.copy()
    moved[:3, 3] += 1.5 * across / np.linalg.norm(across)
    evidence = single_view_evidence(cost, frames[1], moved, models[1].focal_point_mm)["A"]
    assert evidence.cost_px2 == pytest.approx(cost.select_views(0)(moved), rel=1e-12)
    assert evidence.move_mm > 1.0
    assert evidence.own_optimum_cost_px2 < 0.5 * evidence.cost_px2
    assert evidence.relative_gain == pytest.approx(evidence.gain_px2 / evidence.own_optimum_cost_px2)
    assert view_disagreement_mm(cost, frames[1], moved, models[1].focal_point_mm)["A"] == evidence.move_mm


def test_view_agreement_weighs_a_move_by_what_it_gains(models, frames):
    from histostudy.pose.verdict import PoseVerdict, check_view_agreement

    T = POSES[1]
    maps = [DistanceMaps(f.view, f.labels, occlusion_aware=True) for f in frames[1]]
    cost = PoseCost(models[1].points, maps).capped(1.0)
    a = frames[1][0].view
    across = np.cross(a.ray_directions(a.project(T[:3, 3][None]))[0], [0.0, 0.0, 1.0])
    moved = T.copy()
    moved[:3, 3] += 1.5 * across / np.linalg.norm(across)
    gain = single_view_evidence(cost, frames[1][:1], moved, models[1].focal_point_mm)["A"].gain_px2
    assert gain > 0

    def judged(limit_mm, **bounds):
        verdict = PoseVerdict(ok=True, reasons=[], rms_distance_px={}, inside_fraction={}, focal_offset_mm=0.0)
        check_view_agreement(verdict, cost, frames[1], moved, models[1].focal_point_mm, limit_mm, **bounds)
        assert verdict.view_gain_px2["A"] == gain
        return verdict

    assert not judged(0.5).ok
    assert judged(0.5, min_gain_px2=2 * gain).ok  # a move bought with too little gain is no conflict
    refused = judged(0.5, min_gain_px2=gain / 2)
    assert not refused.ok and "gaining" in refused.reasons[0]
    refused = judged(None, max_gain_px2=gain / 2)  # however short the move, the gain alone refuses
    assert not refused.ok and "lowers its cost by" in refused.reasons[0]
    assert judged(None, max_gain_px2=2 * gain).ok and judged(None).ok


def test_pose_config_refuses_a_gain_bound_without_its_check():
    from histostudy.pose import PoseConfig

    with pytest.raises(ValueError, match="min_view_gain_px2=0.01 qualifies max_view_disagreement_mm"):
        PoseConfig(min_view_gain_px2=0.01, max_view_disagreement_mm=None)
    with pytest.raises(ValueError, match="max_view_gain_px2 must be None or a finite number > 0, got -1"):
        PoseConfig(max_view_gain_px2=-1)
    assert PoseConfig(max_view_gain_px2=0.1, max_view_disagreement_mm=None).max_view_gain_px2 == 0.1
