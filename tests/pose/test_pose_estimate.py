"""Tests of histostudy.pose.estimate_pose (§II-B.3-4) on synthetic frames with known truth.

Frames carry reference labels rendered from a 0.25 mm digital model (the oracle segmenter reads
them); the image content does not enter the pose, so it is left blank for speed. The oracle stages
are passed explicitly: the defaults are the shipped networks when their weights are present.
"""

import numpy as np
import pytest
from pose_frames import POSES, focal_error, frames_of

from histostudy.geometry import rotation_angle, transform_from_params
from histostudy.imaging import Frame, default_biplane
from histostudy.learning import OracleOrientation, OracleSegmenter, angles_from_direction, beam_direction_of_pose
from histostudy.pose import PoseEstimationError, PoseResult, apply_left_perturbation, estimate_pose
from histostudy.transducer import Feature, TransducerModel, pose_facing


@pytest.fixture(scope="module")
def models():
    return TransducerModel.build(spacing_mm=0.47), TransducerModel.build(spacing_mm=0.25)


ORACLES = dict(segmenter=OracleSegmenter(), orientation=OracleOrientation())


@pytest.fixture(scope="module")
def frames(models):
    return [frames_of(models[1], T) for T in POSES]


@pytest.mark.parametrize("mode", ["paper", "fast"])
@pytest.mark.parametrize("which", [0, 1])
def test_noise_free_biplane_frames_recover_the_focal_point(models, frames, mode, which):
    T = POSES[which]
    res = estimate_pose(frames[which], models[0], rng=np.random.default_rng(1), mode=mode, **ORACLES)
    assert isinstance(res, PoseResult) and res.mode == mode and res.verdict.ok
    assert focal_error(res, T) < 0.1, focal_error(res, T)
    # The axial angle is recovered up to the transducer's half-turn symmetry (screws aside).
    angle = np.rad2deg(rotation_angle(res.T_carm_transducer[:3, :3].T @ T[:3, :3]))
    assert min(angle, 180.0 - angle) < 0.1
    np.testing.assert_allclose(res.focal_point_mm, res.T_carm_transducer[:3, 3], atol=1e-12)
    assert set(res.timings_s) >= {"segmentation", "distance_maps", "orientation", "initialisation",
                                  "refinement", "verdict", "total"}
    assert res.timings_s["total"] >= res.timings_s["refinement"] > 0
    assert res.evaluations > res.iterations > 0 and np.isfinite(res.cost)


def test_per_class_maps_of_eq3_are_biased_by_occluded_classes(models, frames):
    """With priority-resolved labels, eq. 3's per-class maps pull the optimum off by a large
    fraction of a millimetre; the occlusion-aware maps (default) do not."""
    T = POSES[0]
    # eq. 3 as written (the capped refinement hides much of the per-class bias too)
    per_class = estimate_pose(frames[0], models[0], rng=np.random.default_rng(1), mode="fast",
                              distance_maps="per_class", refine_truncation_px=None, **ORACLES)
    aware = estimate_pose(frames[0], models[0], rng=np.random.default_rng(1), mode="fast",
                          refine_truncation_px=None, **ORACLES)
    assert focal_error(per_class, T) > 0.3 > 0.1 > focal_error(aware, T)


#: Two poses of notebook 04's robustness sweep (render 0.25 mm, seed 777, poses 29 and 43) where
#: most of the transducer lies off the detectors: 24-55 % of its points project onto each.
HALF_HIDDEN_POSES = [
    transform_from_params([0.4978, -1.8061, 0.1668, -54.8204, 58.0428, 25.5321]),
    transform_from_params([-1.4025, 2.2697, 1.1127, -63.5939, -2.8917, 5.71]),
]


def _missing_stretch(frames, feature, view_index=0):
    """The frames with ``feature``'s pixels in the left half of the view's feature erased (to the
    transducer class): a segmentation that missed a stretch of that class, as a U-Net does."""
    out = []
    for i, f in enumerate(frames):
        labels = f.labels.copy()
        if i == view_index:
            rows, cols = np.nonzero(labels == feature)
            cut = np.median(cols)
            labels[rows[cols < cut], cols[cols < cut]] = Feature.TRANSDUCER
        out.append(Frame(f.image, f.view, labels=labels, T_carm_transducer=f.T_carm_transducer))
    return out


@pytest.mark.parametrize("feature", [Feature.GAPS, Feature.OUTER_BOUNDARY])
def test_the_capped_refinement_is_not_pulled_by_a_missed_stretch_of_a_class(models, frames, feature):
    T = POSES[0]
    missed = _missing_stretch(frames[0], feature)
    kwargs = dict(rng=np.random.default_rng(1), mode="fast", raise_on_failure=False, **ORACLES)
    as_written = estimate_pose(missed, models[0], refine_truncation_px=None, verdict_truncation_px=None, **kwargs)
    capped = estimate_pose(missed, models[0], **kwargs)
    # Eq. 3 as written: pulled (gaps 0.7 mm, outer boundary 0.14 mm) and judged implausible (RMS 62 / 17 px).
    assert not as_written.verdict.ok and focal_error(as_written, T) > 0.1
    assert capped.verdict.ok and focal_error(capped, T) < 0.1
    assert focal_error(capped, T) < 0.5 * focal_error(as_written, T)


@pytest.mark.parametrize("which", [0, 1])
def test_the_silhouette_seed_finds_a_mostly_hidden_transducer(models, which, monkeypatch):
    import histostudy.pose.start as pose_module

    T = HALF_HIDDEN_POSES[which]
    frames = frames_of(models[0], T)
    inside = [float(np.mean(f.labels > 0)) for f in frames]
    result = estimate_pose(frames, models[0], mode="fast", rng=np.random.default_rng(0), **ORACLES)
    assert focal_error(result, T) < 0.2, inside
    focal_local = np.append(models[0].focal_point_mm, 1.0)

    def init_error(r):
        return float(np.linalg.norm((r.init.T_carm_transducer @ focal_local)[:3] - T[:3, 3]))

    assert init_error(result) < 0.2
    # Without the seed the initialisation's optimum lies in the wrong region (33 and 56 mm off),
    # even on exact labels. Whether the refinement of its other hypotheses finds the way back
    # from there depends on the cap (measured: pose 0 ends 1.5 mm off at 3 px, pose 1 56 mm off
    # at 1 px), so the seed is judged by the initialisation.
    monkeypatch.setattr(pose_module, "silhouette_candidates", lambda *args, **kwargs: [])
    seedless = estimate_pose(frames, models[0], mode="fast", rng=np.random.default_rng(0), raise_on_failure=False,
                             **ORACLES)
    assert init_error(seedless) > 10.0, init_error(seedless)


def test_same_generator_seed_gives_the_same_pose(models, frames):
    a = estimate_pose(frames[1], models[0], segmenter=OracleSegmenter(), orientation=OracleOrientation(),
                      rng=np.random.default_rng(5), mode="fast")
    b = estimate_pose(frames[1], models[0], segmenter=OracleSegmenter(), orientation=OracleOrientation(),
                      rng=np.random.default_rng(5), mode="fast")
    np.testing.assert_array_equal(a.T_carm_transducer, b.T_carm_transducer)


def test_warm_start_skips_the_initialisation(models, frames):
    T = POSES[1]
    start = apply_left_perturbation(T, [0.01, -0.01, 0.005, 1.0, -0.8, 0.5])
    res = estimate_pose(frames[1], models[0], initial_pose=start, mode="fast", **ORACLES)
    assert res.init is None and res.timings_s["initialisation"] == 0.0
    assert focal_error(res, T) < 0.1


def test_a_single_view_is_enough_for_a_pose_facing_it(models):
    T = POSES[1]
    view = default_biplane()[0]
    frame = frames_of(models[1], T, views=[view])
    res = estimate_pose(frame, models[0], rng=np.random.default_rng(2), mode="fast", **ORACLES)
    assert res.verdict.ok and list(res.verdict.rms_distance_px) == ["A"]
    # Depth along the single beam is seen only through magnification: looser than biplane.
    assert focal_error(res, T) < 0.5, focal_error(res, T)


def test_empty_or_off_detector_frames_raise_a_clear_error(models):
    views = default_biplane()
    empty = [Frame(np.zeros(v.shape, np.float32), v, labels=np.zeros(v.shape, np.uint8),
                   T_carm_transducer=POSES[0]) for v in views]
    with pytest.raises(PoseEstimationError, match="view 'A': no transducer feature"):
        estimate_pose(empty, models[0], **ORACLES)
    far = pose_facing((0.0, 1.0, 0.0), focal_point_mm=(0.0, 0.0, 900.0))
    off = frames_of(models[1], far)
    assert not any(f.labels.any() for f in off)
    with pytest.raises(PoseEstimationError, match="no transducer feature"):
        estimate_pose(off, models[0], **ORACLES)


def test_inconsistent_views_give_a_failed_verdict_not_a_confident_pose(models):
    """Plane B sees the transducer 60 mm away from where plane A sees it: no pose fits both."""
    T = POSES[0]
    shifted = T.copy()
    shifted[:3, 3] += (60.0, 0.0, -40.0)
    frames = frames_of(models[1], T, labels_pose=[None, shifted])
    with pytest.raises(PoseEstimationError, match="implausible pose") as info:
        estimate_pose(frames, models[0], rng=np.random.default_rng(0), mode="fast", **ORACLES)
    assert info.value.verdict is not None and not info.value.verdict.ok
    assert info.value.result is not None
    res = estimate_pose(frames, models[0], rng=np.random.default_rng(0), mode="fast", raise_on_failure=False, **ORACLES)
    assert not res.verdict.ok and any("RMS distance" in r for r in res.verdict.reasons)


def _shifted_across_both_rays(T, shift_mm):
    """The pose moved by ``shift_mm`` along the common normal of both views' rays through its
    focal point: each view sees the move, so labels of plane B from it contradict plane A's."""
    a, b = default_biplane()
    f = T[:3, 3]
    ray_a, ray_b = (v.ray_directions(v.project(f[None]))[0] for v in (a, b))
    normal = np.cross(ray_a, ray_b)
    shifted = T.copy()
    shifted[:3, 3] += shift_mm * normal / np.linalg.norm(normal)
    return shifted


def test_views_that_disagree_by_millimetres_are_refused_although_each_fits_well(models, frames):
    """Plane B's labels are of the pose moved 3.5 mm across both rays: the compromise between the
    views lies about 2.4 mm off with an RMS of only 2-3 px per view, which the RMS check accepts.
    Each view alone pulls the focal point back towards its own reading: refused."""
    T = POSES[0]
    contradicting = frames_of(models[1], T, labels_pose=[None, _shifted_across_both_rays(T, 3.5)])
    kwargs = dict(rng=np.random.default_rng(0), mode="fast", raise_on_failure=False, **ORACLES)
    unchecked = estimate_pose(contradicting, models[0], max_view_disagreement_mm=None, **kwargs)
    assert unchecked.verdict.ok and focal_error(unchecked, T) > 2.0, focal_error(unchecked, T)
    assert max(unchecked.verdict.rms_distance_px.values()) < 4.0 and unchecked.verdict.view_disagreement_mm == {}
    checked = estimate_pose(contradicting, models[0], **kwargs)
    assert not checked.verdict.ok
    assert max(checked.verdict.view_disagreement_mm.values()) > 1.5
    assert any("the views disagree" in r for r in checked.verdict.reasons), checked.verdict.reasons
    # Where the views agree, neither pulls: a few tenths of a millimetre at most.
    agree = estimate_pose(frames[0], models[0], **kwargs)
    moves = agree.verdict.view_disagreement_mm
    assert agree.verdict.ok and max(moves.values()) < 0.5, moves
    # The contradiction also shows in what each view's own optimum gains: 10x the agreeing views' most.
    agreeing_gain = max(agree.verdict.view_gain_px2.values())
    assert max(checked.verdict.view_gain_px2.values()) > 10 * agreeing_gain, (checked.verdict, agree.verdict)
    by_gain = estimate_pose(contradicting, models[0], max_view_disagreement_mm=None,
                            max_view_gain_px2=10 * agreeing_gain, **kwargs)
    assert not by_gain.verdict.ok and any("lowers its cost by" in r for r in by_gain.verdict.reasons)
    assert estimate_pose(frames[0], models[0], max_view_disagreement_mm=None, max_view_gain_px2=10 * agreeing_gain,
                         **kwargs).verdict.ok


def test_the_fast_refinement_runs_to_the_minimum_of_its_capped_cost(models, frames):
    """Labels with Table I's errors make the capped cost's valley long and flat: a refinement that
    stopped at a 1e-3 relative decrease left pose 0's focal point 0.40 mm short of the minimum
    (error 0.33 mm, 0.11 mm at the minimum). Run on, it ends within a few hundredths."""
    from histostudy.pose import DistanceMaps, PoseCost, refine_levenberg_marquardt

    res = estimate_pose(frames[0], models[0], segmenter=OracleSegmenter.named("table1"),
                        orientation=OracleOrientation(), rng=np.random.default_rng(3), mode="fast")
    maps = [DistanceMaps(f.view, lab, occlusion_aware=True) for f, lab in zip(frames[0], res.labels)]
    capped = PoseCost(models[0].points, maps).capped(1.0)
    minimum = refine_levenberg_marquardt(capped, res.T_carm_transducer, max_iter=300, ftol=1e-9, xtol_mm=1e-6,
                                         xtol_rad=1e-8)
    assert np.linalg.norm(minimum.T[:3, 3] - res.T_carm_transducer[:3, 3]) < 0.05
    assert focal_error(res, POSES[0]) < 0.2, focal_error(res, POSES[0])


def test_a_pose_that_leaves_much_of_the_segmentation_unexplained_is_refused(models, frames):
    """A segmentation that also marks a large patch of background: no pose of the model explains
    it, so however well the model fits its own part, the pose is refused."""
    T = POSES[0]
    patched = []
    for i, f in enumerate(frames[0]):
        labels = f.labels.copy()
        if i == 1:
            labels[:250, :250] = Feature.TRANSDUCER
        patched.append(Frame(f.image, f.view, labels=labels, T_carm_transducer=T))
    kwargs = dict(rng=np.random.default_rng(0), mode="fast", raise_on_failure=False, largest_component=False,
                  **ORACLES)
    res = estimate_pose(patched, models[0], **kwargs)
    assert not res.verdict.ok and res.verdict.unexplained_fraction["B"] > 0.1
    assert any("of the segmented transducer lies over" in r for r in res.verdict.reasons), res.verdict.reasons
    unchecked = estimate_pose(patched, models[0], max_unexplained_fraction=None, **kwargs)
    assert unchecked.verdict.unexplained_fraction == {}


def test_a_separate_false_positive_patch_is_dropped_before_the_pose_is_sought(models, frames):
    """The transducer projects as one body: a patch of the segmentation apart from it is a false
    positive, dropped with ``largest_component`` (default), so it neither pulls nor fails the pose."""
    T = POSES[0]
    patched = [Frame(f.image, f.view, labels=f.labels.copy(), T_carm_transducer=T) for f in frames[0]]
    patched[1].labels[:120, :120] = Feature.TRANSDUCER
    res = estimate_pose(patched, models[0], rng=np.random.default_rng(0), mode="fast", **ORACLES)
    assert res.verdict.ok and focal_error(res, T) < 0.1
    assert not res.labels[1][:120, :120].any() and res.verdict.unexplained_fraction["B"] < 0.01


def test_the_verdict_reports_each_class_fit_and_judges_the_element_body(models, frames):
    kwargs = dict(rng=np.random.default_rng(1), mode="fast", raise_on_failure=False, **ORACLES)
    res = estimate_pose(frames[0], models[0], **kwargs)
    body = {view: per_class["transducer"] for view, per_class in res.verdict.class_rms_distance_px.items()}
    assert set(body) == {"A", "B"} and max(body.values()) < 0.2, res.verdict.class_rms_distance_px
    assert set(res.verdict.class_rms_distance_px["A"]) == {f.name.lower() for f in Feature if f != Feature.BACKGROUND}
    strict = estimate_pose(frames[0], models[0], max_body_rms_px=0.01, retry_hypotheses=False, **kwargs)
    assert not strict.verdict.ok and any("element body" in r for r in strict.verdict.reasons)
    # With eq. 3's per-class maps a body point under a thin feature is off its class: not judged.
    per_class = estimate_pose(frames[0], models[0], max_body_rms_px=0.01, distance_maps="per_class", **kwargs)
    assert not any("element body" in r for r in per_class.verdict.reasons)


class _OneViewMisread:
    """The true angles in every view but ``misread``, whose azimuth is off by ``error_deg``: a
    VGG19 that misreads one view (measured on the shipped network: about 1 pose in 8)."""

    def __init__(self, misread: str, error_deg: float):
        self.misread, self.error_deg = misread, error_deg

    def estimate(self, frame, rng):
        az, el = OracleOrientation(0.0, 0.0).estimate(frame, rng)
        return (az + np.deg2rad(self.error_deg), el) if frame.view.name == self.misread else (az, el)


@pytest.mark.parametrize("which", [0, 1])
def test_views_that_disagree_on_the_orientation_start_from_each_views_own_direction(models, frames, which):
    T = POSES[which]
    misread = _OneViewMisread("B", 100.0)
    res = estimate_pose(frames[which], models[0], segmenter=OracleSegmenter(), orientation=misread,
                        rng=np.random.default_rng(1), mode="fast")
    assert res.init.stages["direction_spread_deg"] > 15.0
    assert res.init.stages["direction_starts"] == 5  # the mean direction and each view's two mirrors
    assert res.verdict.ok and focal_error(res, T) < 0.1, focal_error(res, T)
    # Views that agree start from their combined direction alone, as §II-B.4.
    agree = estimate_pose(frames[which], models[0], rng=np.random.default_rng(1), mode="fast", **ORACLES)
    assert agree.init.stages["direction_starts"] == 1
    if which == 0:
        # Without the extra starts, the averaged direction (about 50 deg off) sends this one astray.
        off = estimate_pose(frames[which], models[0], segmenter=OracleSegmenter(), orientation=misread,
                            rng=np.random.default_rng(1), mode="fast", direction_spread_limit_deg=180.0,
                            raise_on_failure=False, retry_hypotheses=False)
        assert off.init.stages["direction_starts"] == 1
        assert not off.verdict.ok and focal_error(off, T) > 10.0


class _MirrorInView:
    """The true angles in view ``mirror_of``; every other view reads the direction that is its
    mirror image on that view's detector plane: the views agree, on the wrong mirror."""

    def __init__(self, mirror_of: str):
        self.mirror_of = mirror_of

    def estimate(self, frame, rng):
        if frame.view.name == self.mirror_of:
            return angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        view = next(v for v in default_biplane() if v.name == self.mirror_of)
        R = view.detector_axes
        mirrored = R.T @ np.diag([1.0, 1.0, -1.0]) @ R @ beam_direction_of_pose(frame.T_carm_transducer)
        return angles_from_direction(mirrored, frame.view)


def test_views_that_agree_on_a_wrong_direction_are_retried_from_each_views_own_direction(models, frames):
    T = POSES[0]
    mirrored = _MirrorInView("A")
    kwargs = dict(segmenter=OracleSegmenter(), orientation=mirrored, rng=np.random.default_rng(1), mode="fast")
    no_retry = estimate_pose(frames[0], models[0], retry_hypotheses=False, raise_on_failure=False, **kwargs)
    assert no_retry.init.stages["direction_spread_deg"] < 1.0 and no_retry.init.stages["direction_starts"] == 1
    assert not no_retry.verdict.ok
    res = estimate_pose(frames[0], models[0], **kwargs)
    assert res.init.stages["direction_starts"] == 5 and res.retries >= 1
    assert res.verdict.ok and focal_error(res, T) < 0.1, focal_error(res, T)


def test_bad_arguments_raise(models, frames):
    with pytest.raises(ValueError, match="at least one Frame"):
        estimate_pose([], models[0], **ORACLES)
    with pytest.raises(TypeError, match=r"frames\[1\] must be a histostudy.imaging.frame.Frame"):
        estimate_pose([frames[0][0], "B"], models[0], **ORACLES)
    with pytest.raises(ValueError, match="max_view_disagreement_mm must be None or a finite number > 0, got -1"):
        estimate_pose(frames[0], models[0], max_view_disagreement_mm=-1, **ORACLES)
    with pytest.raises(TypeError, match="model must be a TransducerModel"):
        estimate_pose(frames[0], {"points": 1}, **ORACLES)
    with pytest.raises(ValueError, match="mode must be one of"):
        estimate_pose(frames[0], models[0], mode="gpu", **ORACLES)
    with pytest.raises(ValueError, match="init must be one of"):
        estimate_pose(frames[0], models[0], init="random", **ORACLES)
    with pytest.raises(ValueError, match="distance_maps must be one of"):
        estimate_pose(frames[0], models[0], distance_maps="chamfer", **ORACLES)
    with pytest.raises(TypeError, match="rng must be a numpy.random.Generator or an int seed"):
        estimate_pose(frames[0], models[0], rng="3", **ORACLES)
    with pytest.raises(ValueError, match="direction_spread_limit_deg must be a number in"):
        estimate_pose(frames[0], models[0], direction_spread_limit_deg=0, **ORACLES)


def test_default_stages_are_the_shipped_networks_when_good_enough_else_the_oracles(monkeypatch):
    import types

    import histostudy.pose.learned_stages as pose

    good_seg = types.SimpleNamespace(manifest={"validation": {"pixel_accuracy": 0.97}})
    good_orient = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 1.5, "elevation_mae_deg": 2.5}})
    poor_orient = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 84.6, "elevation_mae_deg": 24.9}})
    monkeypatch.setattr(pose, "default_segmenter", lambda: good_seg)
    monkeypatch.setattr(pose, "default_orientation", lambda segmenter=None: good_orient)
    pose.default_stages.cache_clear()
    try:
        assert pose.default_stages() == (good_seg, good_orient)
        pose.default_stages.cache_clear()
        monkeypatch.setattr(pose, "default_orientation", lambda segmenter=None: poor_orient)
        with pytest.warns(UserWarning, match="VGG19.s validation angle MAE 84.6 deg exceeds 30.0"):
            seg, orient = pose.default_stages()
        assert isinstance(seg, OracleSegmenter) and isinstance(orient, OracleOrientation)
        pose.default_stages.cache_clear()
        monkeypatch.setattr(pose, "default_segmenter", lambda: None)
        with pytest.warns(UserWarning, match="no usable shipped U-Net"):
            seg, _ = pose.default_stages()
        assert isinstance(seg, OracleSegmenter)
    finally:
        pose.default_stages.cache_clear()


def test_a_segmenter_returning_values_outside_the_feature_classes_is_refused(models, frames):
    class Wrapping:  # what a network's raw argmax over a wrong head, or a cast from int16, can give
        def segment(self, frame, rng):
            return np.full(frame.shape, 300, dtype=np.int64)

    with pytest.raises(ValueError, match=r"the segmentation of view .* must hold Feature values 0..5.*\[300\]"):
        estimate_pose(frames[0], models[0], segmenter=Wrapping(), orientation=OracleOrientation(),
                      rng=np.random.default_rng(0))
