"""The per-experiment and per-acquisition scatter sources (replacement, C-arm reproducibility) and the
robot's accuracy: appended streams (off, every number is today's), and on, each spreads what it
acts on by its magnitude (checked against an independent computation)."""

import dataclasses

import numpy as np
import pytest

from histostudy.imaging import default_biplane
from histostudy.robot import HOME_JOINTS_RAD, UR5E, SimulatedUR5e, forward_kinematics
from histostudy.study.budget._magnitudes import CarmReproducibility, RobotAccuracy, TransducerReplacement
from histostudy.study.budget._sources import LAB_SOURCES, LabErrorModel, draw_lab
from histostudy.study.targeting.robots import InaccurateArm, KinematicError, reported_flange_pose
from histostudy.transducer import TransducerModel, TransducerSpec

FIRST_EIGHT = ("manufacturing", "bubble_offset", "projection", "gantry_sag", "registration", "annotation", "robot",
               "phantom_motion")
NEW = ("replacement", "carm_reproducibility", "robot_accuracy")


@pytest.fixture(scope="module")
def physical():
    return TransducerModel.build_physical(TransducerSpec(), 0.94, rng=np.random.default_rng(np.random.SeedSequence(4)))


def _without_new(model):
    return dataclasses.replace(model, **{name: None for name in NEW})


def test_new_sources_are_appended_so_no_existing_stream_moves(physical):
    assert LAB_SOURCES[:8] == FIRST_EIGHT and LAB_SOURCES[8:] == NEW
    views = default_biplane()
    full = draw_lab(LabErrorModel(manufacturing=None), 7, physical=physical, views=views)
    old = draw_lab(_without_new(LabErrorModel(manufacturing=None)), 7, physical=physical, views=views)
    # today's numbers of this lab (drawn before the new sources existed)
    assert np.allclose(old.bubble_offset_mm, [0.7009550603158944, 0.4267101649844001, 3.05630239701777],
                       rtol=0, atol=1e-15)
    assert np.array_equal(full.bubble_offset_mm, old.bubble_offset_mm)
    for u, v in zip(full.estimator_views + full.frame_views, old.estimator_views + old.frame_views):
        assert np.array_equal(u.P, v.P)
    for e in (0, 3, 10_000):
        a, b = full.experiment(e), old.experiment(e)
        for field in ("T_cbct_carm", "annotation_centroid_mm", "annotation_radius_mm", "phantom_motion_mm"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
    # off: no change anywhere they act
    assert not np.any(old.experiment(2).bubble_offset_change_mm)
    assert old.bubble_offset_at(2) is old.bubble_offset_mm
    assert old.acquisition_views(2, 1, old.estimator_views) == old.estimator_views
    assert old.kinematic_error() is None


def test_replacement_spreads_the_bubble_offset_by_its_sd_per_experiment(physical):
    sd = (0.2, 0.3, 0.6)
    model = LabErrorModel(manufacturing=None, replacement=TransducerReplacement(sd_mm=sd)).only("replacement")
    model = dataclasses.replace(model, bubble_offset=LabErrorModel().bubble_offset)
    lab = draw_lab(model, 3, physical=physical, views=default_biplane())
    offsets = np.array([lab.bubble_offset_at(e) for e in range(600)])
    assert np.allclose(offsets.std(axis=0), sd, rtol=0.12)
    assert np.allclose(offsets.mean(axis=0), lab.bubble_offset_mm, atol=3 * np.array(sd) / np.sqrt(600))
    assert np.array_equal(lab.bubble_offset_at(5), lab.bubble_offset_at(5))  # stateless
    # the lab's offset itself is the one drawn without the replacement
    assert np.array_equal(lab.bubble_offset_mm, draw_lab(model.without("replacement"), 3, physical=physical,
                                                         views=default_biplane()).bubble_offset_mm)


def test_carm_reproducibility_shifts_each_acquisitions_projection_by_its_sd(physical):
    views = default_biplane()
    model = LabErrorModel(carm_reproducibility=CarmReproducibility(shift_mm=0.2)).only("carm_reproducibility")
    lab = draw_lab(model, 5, physical=physical, views=views)
    point = np.array([[4.0, -3.0, 12.0]])
    shifts = np.array([[told.project(point)[0] - v.project(point)[0]
                        for told, v in zip(lab.acquisition_views(e, a, views), views)]
                       for e in range(60) for a in range(7)])  # (n, plane, uv) px
    expected_px = 0.2 / views[0].pixel_mm
    assert np.allclose(shifts.std(axis=0), expected_px, rtol=0.12)
    assert abs(np.corrcoef(shifts[:, 0, 0], shifts[:, 1, 0])[0, 1]) < 0.15  # planes drawn independently
    again = lab.acquisition_views(3, 2, views)
    assert all(np.array_equal(u.P, v.P) for u, v in zip(again, lab.acquisition_views(3, 2, views)))
    assert lab.frame_views == tuple(views)  # the frames keep the true geometry


def _tcp_errors(error: KinematicError, rng: np.random.Generator, n: int = 8) -> np.ndarray:
    tool = np.eye(4)
    tool[2, 3] = 250.0
    out = []
    for _ in range(n):
        q = np.array(HOME_JOINTS_RAD) + rng.uniform(-0.5, 0.5, 6)
        out.append(np.linalg.norm((error.flange_pose(q) @ tool)[:3, 3] - (forward_kinematics(q, UR5E) @ tool)[:3, 3]))
    return np.array(out)


def test_robot_accuracy_draws_arms_with_the_stated_rms_tcp_error(physical):
    model = LabErrorModel(robot_accuracy=RobotAccuracy(position_mm=0.5)).only("robot_accuracy")
    rng = np.random.default_rng(2024)
    errors = np.concatenate([_tcp_errors(draw_lab(model, seed, physical=physical, views=default_biplane())
                                         .kinematic_error(), rng) for seed in range(150)])
    assert np.sqrt(np.mean(errors ** 2)) == pytest.approx(0.5, rel=0.15)
    lab = draw_lab(model, 1, physical=physical, views=default_biplane())
    assert np.array_equal(lab.kinematic_error().theta_rad, lab.kinematic_error().theta_rad)


def test_an_inaccurate_arm_reports_the_nominal_pose_and_sits_at_the_true_one():
    error = KinematicError.from_normals(np.random.default_rng(8).normal(size=(4, 6)), length_sd_mm=0.2,
                                        angle_sd_rad=0.2 / 500)
    arm = InaccurateArm(SimulatedUR5e(3, repeatability_mm=0.0), error)
    target = forward_kinematics(HOME_JOINTS_RAD, UR5E)
    target[:3, 3] += [10.0, -5.0, 8.0]
    reached = arm.move_linear(target)
    assert np.allclose(reported_flange_pose(arm), target, atol=1e-9)  # the controller's own reading
    assert np.allclose(reached, error.flange_pose(arm.joints()), atol=1e-12)
    assert 0.05 < np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 5.0
    exact = InaccurateArm(SimulatedUR5e(3, repeatability_mm=0.0), KinematicError(*np.zeros((4, 6))))
    assert np.array_equal(exact.move_linear(target), SimulatedUR5e(3, repeatability_mm=0.0).move_linear(target))
    plain = SimulatedUR5e(3)
    assert np.array_equal(reported_flange_pose(plain), plain.flange_pose())


@pytest.mark.slow
def test_the_scatter_sources_act_in_the_budget_where_they_act():
    from histostudy.study.budget._run import BudgetSetup, budget_configurations, run_error_budget
    from histostudy.study.pose.experiments import PoseStudyConfig, experiment_setups
    from histostudy.study.pose.geometry import transducer_axes
    from histostudy.study.targeting.setup import TargetingStudyConfig

    model = TransducerModel.build(spacing_mm=0.94)
    physical = TransducerModel.build_physical(spacing_mm=0.94, rng=np.random.default_rng(3))
    lab_model = dataclasses.replace(LabErrorModel().off(), **{s: getattr(LabErrorModel(), s) for s in NEW})
    lab = draw_lab(lab_model, 21, physical=physical, views=default_biplane())
    pose = PoseStudyConfig(n_experiments=1, modes=("fast",), track=False, n_splats=2, background="phantom")
    targeting = TargetingStudyConfig(n_experiments=1, n_splats=2, background="none", bias_correction=False)
    setup = BudgetSetup(lab, pose, targeting, model, model)
    configurations = [c for c in budget_configurations(lab_model) if c[0] != "lab" and not c[0].startswith("without")]
    records = run_error_budget(setup, seed=5, configurations=configurations, studies=("pose",))
    pose_rows = records.set_index("configuration")
    dirs = ("depth", "tb", "lr")
    err = {c: np.array([pose_rows.loc[c, f"centre_err_{d}"] for d in dirs]) for c in pose_rows.index}
    # the re-placed transducer moves the treated zone (the reference) by its change, not the estimate
    T = experiment_setups(pose, 5)[0].T_true["centre"]
    axes = np.array([transducer_axes(T)[d] for d in dirs])
    shift = axes @ (T[:3, :3] @ lab.experiment(0).bubble_offset_change_mm)
    assert np.allclose(err["only replacement"], err["baseline"] - shift, atol=0.35)
    # a shifted projection moves the estimate a little (0.1 mm at the detector, a fraction at the object)
    assert 1e-6 < np.linalg.norm(err["only carm_reproducibility"] - err["baseline"]) < 0.5
    assert np.array_equal(err["only robot_accuracy"], err["baseline"])  # not modelled in the pose study
    # the lab's arm lands the targeting zone elsewhere than the exact arm (the two configurations only:
    # each configuration's records are the same whichever others run beside it)
    arm = [c for c in configurations if c[0] in ("baseline", "only robot_accuracy")]
    target = run_error_budget(setup, seed=5, configurations=arm, studies=("targeting",)).set_index("configuration")
    assert target.loc["only robot_accuracy", "ok"] and target.loc["baseline", "ok"]
    moved = abs(target.loc["only robot_accuracy", "err_euclidean"] - target.loc["baseline", "err_euclidean"])
    assert 1e-6 < moved < 3.0
