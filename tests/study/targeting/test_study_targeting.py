"""The automated targeting study (notebook 05): one small experiment end to end, against known truth.

Coarse and fast: the 0.47 mm model renders the frames (no scene behind the transducer, 4 splats),
1 mm phantom and CBCT voxels, a 3x3x4 mm treatment lattice. The experiment injects a known
bubble-cloud offset, so the uncorrected targeting must show it and the bias correction remove it.
"""

import numpy as np
import pytest

from histostudy.calibration import R_BASE_FLANGE_DOWN, calibrate
from histostudy.geometry import make_transform
from histostudy.imaging import default_biplane
from histostudy.learning import OracleOrientation
from histostudy.robot import HOME_JOINTS_RAD, RobotError, SimulatedUR5e, inverse_kinematics_closest
from histostudy.study import targeting as T
from histostudy.study.targeting._calibration import calibrate_robot
from histostudy.study.targeting._positioning import position_for_target, scene_at_target, target_orientation
from histostudy.study.targeting._summary import summary, targeting_values
from histostudy.study.targeting.experiment import run_targeting_experiment
from histostudy.study.targeting.robots import rtde_robot, sim_robot
from histostudy.study.targeting.setup import TargetingError, TargetingStudyConfig, draw_ground_truth, start_joints
from histostudy.transducer import TransducerModel, TransducerSpec

#: Bubble cloud 1.5 mm to the transducer's +x (LR) and 1.5 mm deeper (-z) than the physical focal point.
OFFSET = (1.5, 0.0, -1.5)
SEED = 11


def small_config(**kw) -> TargetingStudyConfig:
    base = dict(n_experiments=1, zone_diameters_mm=(20.0,), background="none", n_splats=4, phantom_voxel_mm=1.0,
                cbct_voxel_mm=1.0, treatment_spacing_mm=(3.0, 3.0, 4.0), bubble_offset_mm=OFFSET)
    base.update(kw)
    return TargetingStudyConfig(**base)


@pytest.fixture(scope="module")
def models():
    spec = TransducerSpec()
    model = TransducerModel.build(spec, spacing_mm=0.47)
    physical = TransducerModel.build_physical(spec, spacing_mm=0.47, rng=np.random.default_rng(3))
    return model, physical, default_biplane()


@pytest.fixture(scope="module")
def experiment(models):
    model, physical, views = models
    return run_targeting_experiment(small_config(), np.random.SeedSequence(SEED), pose_model=model,
                                      render_model=model, physical=physical, views=views)


def test_calibration_recovers_the_true_set_up(experiment):
    e = experiment
    # The study's bound on the residuals passed (else calibrate_robot raises); against the truth:
    assert e["cal_max_rotation_residual_deg"] < 1.0
    assert e["cal_X_rotation_deg"] < 1.0
    assert e["cal_X_translation_mm"] < 3.0  # along the tool axis, 200-300 mm from the flange
    assert e["cal_Y_rotation_deg"] < 1.0
    # Where the true chain puts the digital focal point for the commanded flange pose.
    assert e["cal_error_at_target_mm"] < 1.0


def test_uncorrected_targeting_shows_the_injected_bubble_offset(experiment, models):
    e = experiment
    physical = models[1]
    # Expected error in the transducer frame: the offset plus the physical focal point's deviation.
    expected = np.asarray(OFFSET) + physical.focal_point_mm
    expected_dirs = {"lr": expected[0], "tb": expected[1], "depth": -expected[2]}
    for d, v in expected_dirs.items():
        assert e[f"err_{d}"] == pytest.approx(v, abs=0.8), d
    assert e["err_euclidean"] == pytest.approx(np.linalg.norm(expected), abs=0.8)
    # The learnt bias (depth/TB/LR) is what the calibration treatment saw: the same offset.
    for d, v in expected_dirs.items():
        assert e[f"bias_learnt_{d}"] == pytest.approx(v, abs=0.8), d
    # The segmented zone is about the planned size (the segmentation shrinks a curved zone a little).
    assert abs(e["radius_err_mm"]) < 2.0  # 3x3x4 mm lattice: gaps at the rim shrink it


def test_bias_correction_removes_the_offset(experiment):
    e = experiment
    assert e["corr_err_euclidean"] < 1.0
    assert e["corr_err_euclidean"] < 0.5 * e["err_euclidean"]
    assert abs(e["corr_radius_err_mm"]) < 2.0


def test_summary_tables(experiment):
    import pandas as pd

    records = pd.DataFrame([{"robot": "sim", **experiment}])
    v = targeting_values(records)
    assert v["targeting.euclidean"][0] == pytest.approx(experiment["err_euclidean"])
    assert v["targeting.bias.depth"][0] == pytest.approx(experiment["err_depth"])
    assert v["targeting.mae.lr"][0] == pytest.approx(abs(experiment["err_lr"]))
    vc = targeting_values(records, "corr_")
    assert vc["targeting.euclidean"][0] == pytest.approx(experiment["corr_err_euclidean"])
    table = summary(records)
    assert list(table["targeting"]) == ["uncorrected (paper)", "bias-corrected"]
    with pytest.raises(ValueError, match="empty"):
        targeting_values(records.iloc[:0])


def _exact_calibration(rng):
    truth = draw_ground_truth(rng, small_config())
    F = T.calibration_poses(rng, small_config(), truth)
    cal = calibrate(F, [truth.T_carm_transducer(f) for f in F])
    return truth, cal


def test_target_out_of_reach_raises_before_any_move():
    rng = np.random.default_rng(5)
    truth, cal = _exact_calibration(rng)
    start = make_transform(R_BASE_FLANGE_DOWN, truth.start_focal_base_mm - R_BASE_FLANGE_DOWN
                           @ truth.T_flange_transducer_nominal[:3, 3])
    robot = SimulatedUR5e(0, initial_joints_rad=inverse_kinematics_closest(start, HOME_JOINTS_RAD))
    R = target_orientation(cal)
    # A reachable target near the isocentre is reached with the focal point on it (exact calibration).
    position_for_target(robot, cal, [0.0, 0.0, 0.0], R)
    assert robot.state().moves_completed == 1
    true_focal = truth.T_carm_transducer(robot.flange_pose())[:3, 3]
    assert np.linalg.norm(true_focal) < 0.05  # robot repeatability only
    assert np.allclose(robot.tcp_offset(), cal.T_flange_transducer)
    # 1.5 m beyond the isocentre, away from the base: out of the UR5e's 850 mm reach.
    q_before = robot.joints()
    with pytest.raises(RobotError):
        position_for_target(robot, cal, [1500.0, 0.0, 0.0], R)
    assert robot.state().moves_completed == 1
    assert np.array_equal(robot.joints(), q_before)
    with pytest.raises(ValueError, match="target_mm"):
        position_for_target(robot, cal, [np.nan, 0.0, 0.0], R)


def test_scene_at_target_puts_the_true_focal_point_on_the_target():
    from histostudy.robot import forward_kinematics

    rng = np.random.default_rng(5)
    truth, cal = _exact_calibration(rng)
    target = truth.T_carm_phantom[:3, 3] + [3.0, -2.0, 4.0]
    R = target_orientation(cal)
    scene = scene_at_target(truth, cal, target, R)
    assert np.array_equal(scene["T_carm_base"], truth.T_carm_base)
    assert np.array_equal(scene["T_carm_phantom"], truth.T_carm_phantom)
    # The joints reach the commanded flange pose, and the true chain (exact calibration) puts the
    # transducer's focal point on the target with the commanded orientation.
    assert scene["joints_rad"].shape == (6,)
    assert np.allclose(forward_kinematics(scene["joints_rad"]), scene["T_base_flange"], atol=1e-6)
    T_true = truth.T_carm_base @ scene["T_base_flange"] @ truth.T_flange_transducer
    assert np.allclose(scene["T_carm_transducer"], T_true)
    assert np.linalg.norm(scene["T_carm_transducer"][:3, 3] - target) < 1e-6
    assert np.allclose(scene["T_carm_transducer"][:3, :3], R, atol=1e-6)
    with pytest.raises(ValueError, match="target_mm"):
        scene_at_target(truth, cal, [0.0, np.inf, 0.0], R)
    with pytest.raises(TypeError, match="calibration"):
        scene_at_target(truth, None, target, R)


def test_ground_truth_is_plausible_and_seeded():
    cfg = small_config()
    a = draw_ground_truth(np.random.default_rng(1), cfg)
    b = draw_ground_truth(np.random.default_rng(1), cfg)
    assert np.array_equal(a.T_carm_base, b.T_carm_base)
    for seed in range(10):
        t = draw_ground_truth(np.random.default_rng(seed), cfg)
        base_in_carm = t.T_carm_base[:3, 3]
        assert 500.0 <= np.linalg.norm(base_in_carm) <= 750.0
        assert base_in_carm[1] > 0  # the base stands below the isocentre (LPS +y is posterior)
        focal_flange = np.linalg.norm(t.T_flange_transducer[:3, 3])
        assert 190.0 <= focal_flange <= 310.0
        # The transducer points down with the flange at the calibration poses (tilted by 15 deg).
        for F in T.calibration_poses(np.random.default_rng(seed), cfg, t):
            z = t.T_carm_transducer(F)[:3, 2]  # from the focal point towards the transducer
            assert np.degrees(np.arccos(-z[1])) < 20.0


@pytest.mark.parametrize("kw, match", [
    (dict(n_calibration_poses=2), "n_calibration_poses"),
    (dict(zone_diameters_mm=(40.0,)), "zone_diameters_mm"),
    (dict(background="room"), "background"),
    (dict(bubble_offset_mm=(1.0, 2.0)), "bubble_offset_mm"),
    (dict(n_experiments=0), "n_experiments"),
    (dict(degradation="unet"), "degradation must be one of"),
])
def test_config_rejects_bad_input(kw, match):
    with pytest.raises(ValueError, match=match):
        small_config(**kw)


def test_rtde_robot_gives_the_same_numbers(experiment, models):
    """The same experiment through the real ur_rtde client against the simulated controller."""
    pytest.importorskip("rtde_control")
    model, physical, views = models
    row = run_targeting_experiment(small_config(), np.random.SeedSequence(SEED), pose_model=model,
                                     render_model=model, physical=physical, views=views,
                                     robot_factory=rtde_robot(small_config()))
    assert row["moves"] == experiment["moves"]
    assert np.allclose(row["robot_final_tcp_mm"], experiment["robot_final_tcp_mm"], rtol=0, atol=1e-6)
    for key, value in experiment.items():
        if isinstance(value, float):
            assert row[key] == pytest.approx(value, abs=1e-6), key


def test_the_same_seed_sequence_gives_the_same_set_up_twice(models):
    """run_targeting_experiment must not consume its SeedSequence (spawn is stateful)."""
    seq = np.random.SeedSequence(SEED)
    model, physical, views = models
    with pytest.raises(TypeError, match="SeedSequence"):
        run_targeting_experiment(small_config(), SEED, pose_model=model, render_model=model, physical=physical,
                                   views=views)
    before = seq.n_children_spawned
    calls = []

    class Stop(Exception):
        pass

    def factory(seed, q):
        calls.append((seed, np.asarray(q).copy()))
        raise Stop

    for _ in range(2):
        with pytest.raises(Stop):
            run_targeting_experiment(small_config(), seq, pose_model=model, render_model=model, physical=physical,
                                       views=views, robot_factory=factory)
    assert seq.n_children_spawned == before
    assert calls[0][0] == calls[1][0] and np.array_equal(calls[0][1], calls[1][1])


def test_the_calibration_runs_on_the_stages_it_is_given(models):
    """Notebook 05 passes the learned stages: every calibration frame goes through the segmenter
    and the orientation given (not the config's oracles), and a segmenter that finds nothing stops
    the study with a clear error before anything is calibrated."""
    model, physical, views = models
    config = small_config(degradation="none")
    truth = draw_ground_truth(np.random.default_rng(5), config)
    oracle_segmenter, oracle_orientation = config.segmenter(), OracleOrientation()
    calls = {"segment": 0, "orientation": 0}

    class SpySegmenter:
        def segment(self, frame, rng=None):
            calls["segment"] += 1
            return oracle_segmenter.segment(frame, rng)

    class SpyOrientation:
        def estimate(self, frame, rng=None):
            calls["orientation"] += 1
            return oracle_orientation.estimate(frame, rng)

    class BlindSegmenter:
        def segment(self, frame, rng=None):
            return np.zeros(frame.image.shape, np.uint8)

    def calibrate_with(segmenter, orientation):
        names = ("rng_pose", "rng_scene", "rng_render", "rng_est")
        rngs = {name: np.random.default_rng(k) for k, name in enumerate(names)}
        with sim_robot(config)(7, start_joints(truth)) as robot:
            return calibrate_robot(robot, truth, config, pose_model=model, render_model=model, physical=physical,
                                     views=views, segmenter=segmenter, orientation=orientation, **rngs)

    cal, rows = calibrate_with(SpySegmenter(), SpyOrientation())
    n_frames = config.n_calibration_poses * len(views)
    assert calls == {"segment": n_frames, "orientation": n_frames}
    assert rows["pose_error_mm"].max() < 1.0 and (rows["acquisitions"] == 1).all()
    with pytest.raises(TargetingError, match="calibration pose 0: the pose estimates of all 3 pairs acquired failed"):
        calibrate_with(BlindSegmenter(), SpyOrientation())

    class BlindAtFirst:
        """Finds nothing in the second calibration pose's first pair (its first view), as a pair
        whose estimate the verdict refuses."""

        def __init__(self):
            self.calls = 0

        def segment(self, frame, rng=None):
            self.calls += 1
            if self.calls == len(views) + 1:
                return np.zeros(frame.image.shape, np.uint8)
            return oracle_segmenter.segment(frame, rng)

    again_cal, again = calibrate_with(BlindAtFirst(), OracleOrientation())
    assert list(again["acquisitions"]) == [1, 2] + [1] * (config.n_calibration_poses - 2)
    assert again["pose_error_mm"].max() < 1.0
    # the first pose drew as before; the second pair of pose 1 is a new acquisition
    assert again["pose_error_mm"].iloc[0] == rows["pose_error_mm"].iloc[0]



def test_the_config_renders_with_the_shared_render_settings():
    from histostudy.imaging import FrameRenderConfig

    config = TargetingStudyConfig(n_splats=4, background="none")
    assert isinstance(config, FrameRenderConfig)
    assert config.frame_kwargs() == {"photons_per_pixel": 5e4, "n_splats": 4, "splat_sigma_mm": 0.5, "device": None}
    with pytest.raises(ValueError, match="background must be one of"):
        TargetingStudyConfig(background="water")
    with pytest.raises(ValueError, match="splat_sigma_mm"):
        TargetingStudyConfig(splat_sigma_mm=-1.0)
