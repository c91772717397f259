"""Tests of histostudy.pose.conic_orientation: the transducer axis from its inner boundary's ellipse.

Frames carry reference labels of a 0.25 mm digital model at known poses (the image is blank: the
geometric initialiser reads labels only)."""

import numpy as np
import pytest

from histostudy.imaging import Frame, default_biplane, render_labels
from histostudy.learning import (
    OracleOrientation,
    OracleSegmenter,
    OrientationSource,
    angles_from_direction,
    beam_direction_of_pose,
    direction_candidates,
    orientation_angle_error,
)
from histostudy.pose import ConicOrientation, estimate_pose
from histostudy.pose.conic_orientation import ConicFit
from histostudy.transducer import Feature, TransducerModel, pose_facing

POSES = [
    pose_facing((0.15, 1.0, 0.25), focal_point_mm=(4.0, -6.0, 8.0), axial_rotation_rad=0.35),
    pose_facing((-0.3, 1.0, -0.1), focal_point_mm=(-10.0, 5.0, -3.0), axial_rotation_rad=2.0),
    pose_facing((0.9, 0.6, -0.5), focal_point_mm=(15.0, 0.0, 10.0), axial_rotation_rad=1.0),
]


@pytest.fixture(scope="module")
def fine():
    return TransducerModel.build(spacing_mm=0.25)


@pytest.fixture(scope="module")
def frames(fine):
    views = default_biplane()
    return [[Frame(np.zeros(v.shape, np.float32), v, labels=render_labels(fine, T, v), T_carm_transducer=T)
             for v in views] for T in POSES]


def angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@pytest.mark.parametrize("which", range(len(POSES)))
def test_exact_labels_give_the_true_axis_among_the_two_candidates(frames, which):
    source = ConicOrientation(segmenter=OracleSegmenter())
    truth = beam_direction_of_pose(POSES[which])
    for frame in frames[which]:
        elevation_deg = np.degrees(angles_from_direction(truth, frame.view)[1])
        fit = source.fit(frame.labels, frame.view, np.random.default_rng(0))
        if elevation_deg > 70:
            # nearly edge-on (pose 2, view B: 80 deg) the ellipse is too thin to trust: no fit
            assert fit is None
            continue
        assert isinstance(fit, ConicFit)
        errors = [angle_deg(d, truth) for d in fit.directions]
        # the sign resolved (the focal side, not the axis alone) and the axis refined by the model
        assert min(errors) < 1.0, errors


def test_estimate_gives_angles_of_the_view_and_is_an_orientation_source(frames):
    source = ConicOrientation(segmenter=OracleSegmenter())
    assert isinstance(source, OrientationSource)
    frame = frames[0][0]
    az, el = source.estimate(frame, np.random.default_rng(0))
    ref = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
    # the mean of the two perspective solutions, folded on the detector hemisphere
    assert np.degrees(orientation_angle_error(az, el, *ref)) < 10.0


def test_a_view_without_the_inner_boundary_falls_back_or_says_why(frames):
    frame = frames[0][0]
    labels = frame.labels.copy()
    labels[labels == Feature.INNER_BOUNDARY] = Feature.TRANSDUCER
    fallback = OracleOrientation(azimuth_mae_deg=0.0, elevation_mae_deg=0.0)
    source = ConicOrientation(segmenter=OracleSegmenter(), fallback=fallback)
    assert source.fit(labels, frame.view, np.random.default_rng(0)) is None
    pair = source.direction_candidates_from_labels(frame, labels, np.random.default_rng(0))
    assert np.allclose(pair, direction_candidates(*fallback.estimate(frame, np.random.default_rng(0)), frame.view))
    with pytest.raises(ValueError, match="no usable inner-boundary ellipse"):
        ConicOrientation().direction_candidates_from_labels(frame, labels, np.random.default_rng(0))
    with pytest.raises(ValueError, match="shape"):
        source.fit(labels[:10], frame.view, np.random.default_rng(0))


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="min_inlier_fraction"):
        ConicOrientation(min_inlier_fraction=1.5)
    with pytest.raises(ValueError, match="tolerance_px"):
        ConicOrientation(tolerance_px=-1.0)
    with pytest.raises(TypeError, match="fallback"):
        ConicOrientation(fallback="vgg")
    with pytest.raises(ValueError, match="min_pixels"):
        ConicOrientation(min_pixels=2)


def test_estimate_pose_reads_the_candidates_from_its_own_labels(frames):
    model = TransducerModel.build(spacing_mm=0.47)

    class CountingSegmenter(OracleSegmenter):
        calls = 0

        def segment(self, frame, rng=None):
            type(self).calls += 1
            return super().segment(frame, rng)

    segmenter = CountingSegmenter()
    source = ConicOrientation(segmenter=segmenter)  # would segment again if estimate_pose called estimate()
    res = estimate_pose(frames[0], model, segmenter=segmenter, orientation=source, mode="fast",
                        rng=np.random.default_rng(1))
    assert CountingSegmenter.calls == 2
    assert res.verdict.ok and np.linalg.norm(res.focal_point_mm - POSES[0][:3, 3]) < 0.1
    assert res.init.stages["direction_spread_deg"] < 3.0


def test_the_default_orientation_is_the_conic_with_the_shipped_vgg19_as_fallback():
    from histostudy.learning import LearnedOrientation, UNetRunner, default_segmenter, default_vgg19
    from histostudy.pose import default_orientation, learned_stage_shortfalls

    vgg = default_vgg19()
    if vgg is None or default_segmenter() is None:
        pytest.skip("the shipped networks are not in data/models")
    source = default_orientation()
    assert isinstance(source, ConicOrientation) and isinstance(source.fallback, LearnedOrientation)
    assert isinstance(source.segmenter, UNetRunner)
    # the learned-stage requirements judge the VGG19 behind it
    assert source.manifest["sha256"] == vgg.manifest["sha256"]
    assert learned_stage_shortfalls(default_segmenter(), source) == []


def test_fitting_the_circle_poses_on_threads_gives_the_same_fit(frames):
    from concurrent.futures import ThreadPoolExecutor

    source = ConicOrientation(segmenter=OracleSegmenter())
    frame = frames[0][0]
    alone = source.fit(frame.labels, frame.view, np.random.default_rng(0))
    with ThreadPoolExecutor(max_workers=2) as pool:
        threaded = source.fit(frame.labels, frame.view, np.random.default_rng(0), executor=pool)
    assert isinstance(alone, ConicFit)
    assert np.array_equal(alone.directions, threaded.directions) and alone.sign_scores == threaded.sign_scores
