"""The error budget on small studies: the baseline is the study as it runs, and each source acts
where it acts (the reading of the CBCT, the bubble clouds, the views the estimator is told)."""

import dataclasses

import numpy as np
import pytest

from histostudy.imaging import default_biplane
from histostudy.study.budget._run import (
    BudgetSetup,
    budget_configurations,
    measured_reference,
    measured_zone,
    run_error_budget,
)
from histostudy.study.budget._sources import LabErrorModel, draw_lab
from histostudy.study.pose.experiments import PoseStudyConfig, run_pose_study
from histostudy.study.pose.metrics import experiment_metrics
from histostudy.study.pose.reference import cbct_reference
from histostudy.study.targeting.experiment import run_targeting_experiment
from histostudy.study.targeting.robots import sim_robot
from histostudy.study.targeting.setup import TargetingStudyConfig
from histostudy.transducer import TransducerModel

DIRS = ("depth", "tb", "lr")
#: Half-resolution views: each check compares two runs on the same views, at a quarter of the pixels.
VIEWS = [v.scaled(0.5) for v in default_biplane()]


@pytest.fixture(scope="module")
def models():
    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    return model, physical


def _setup(models, sources, **pose):
    model, physical = models
    lab_model = dataclasses.replace(LabErrorModel().off(), **{s: getattr(LabErrorModel(), s) for s in sources})
    lab = draw_lab(lab_model, 21, physical=physical, views=VIEWS)
    pose_config = PoseStudyConfig(n_experiments=1, modes=("fast",), track=False, n_splats=2, background="phantom",
                                  **pose)
    targeting_config = TargetingStudyConfig(n_experiments=1, n_splats=2, background="none", bias_correction=False)
    return BudgetSetup(lab, pose_config, targeting_config, model, model)


@pytest.mark.slow
def test_pose_budget_baseline_is_the_study_and_sources_act_where_they_act(models):
    setup = _setup(models, ("projection", "bubble_offset", "registration", "annotation", "phantom_motion"))
    every = budget_configurations(setup.lab.model)
    sources = ("bubble_offset", "projection", "registration", "annotation", "phantom_motion")
    assert [label for label, _ in every] == ["baseline", "lab", *(f"{kind} {source}" for kind in ("only", "without")
                                                                  for source in sources)]
    # the configurations asserted on below (a configuration's records do not depend on the others run)
    asserted = {"baseline", "lab", "without projection", "only annotation", "only phantom_motion",
                "only registration", "only bubble_offset", "only projection"}
    records = run_error_budget(setup, seed=5, studies=("pose",),
                               configurations=[c for c in every if c[0] in asserted]).set_index("configuration")
    assert set(records.index) == asserted
    # every source off: Table II of run_pose_study against cbct_reference, number for number
    config = dataclasses.replace(setup.pose_config, assumed_bubble_offset_mm=(0.0, 0.0, 0.0))
    today = run_pose_study(config, pose_model=setup.pose_model, render_model=setup.render_model,
                           physical=setup.lab.study_physical, views=VIEWS, seed=5)
    expected = experiment_metrics(today, reference=cbct_reference(config, physical=setup.lab.study_physical, seed=5))
    base = records.loc["baseline"]
    for column in ("centre_err_euclidean", "radius_err_overall", "margin_err_overall",
                   *(f"centre_err_{d}" for d in DIRS)):
        assert base[column] == expected[column].iloc[0], column
    axes = np.array([_axes(setup, seed=5)[d] for d in DIRS])
    draw = setup.lab.experiment(0)
    reference = cbct_reference(config, physical=setup.lab.study_physical, seed=5)
    centroid = reference[[f"centroid_{a}" for a in "xyz"]].to_numpy(float)[0]
    base_err = np.array([base[f"centre_err_{d}"] for d in DIRS])
    for label, shift in (("only annotation", draw.annotation_centroid_mm), ("only phantom_motion",
                                                                            draw.phantom_motion_mm),
                         ("only registration", draw.T_cbct_carm[:3, :3] @ centroid + draw.T_cbct_carm[:3,
                                                                                                      3] - centroid)):
        err = np.array([records.loc[label, f"centre_err_{d}"] for d in DIRS])
        assert np.allclose(err, base_err - axes @ shift, atol=1e-9), label
    # the bubble offset moves the treated zone (the reference), not the estimate
    err = np.array([records.loc["only bubble_offset", f"centre_err_{d}"] for d in DIRS])
    R = _centre_rotation(setup, seed=5)
    assert np.allclose(err, base_err - axes @ (R @ setup.lab.bubble_offset_mm), atol=0.35)
    # the calibration error changes the estimate (the frames are the same)
    moved = abs(records.loc["only projection", "centre_err_euclidean"] - base["centre_err_euclidean"])
    assert 1e-6 < moved < 2.0
    assert records.loc["lab", "centre_err_euclidean"] != records.loc["without projection", "centre_err_euclidean"]


def _axes(setup, seed):
    from histostudy.study.pose.experiments import experiment_setups
    from histostudy.study.pose.geometry import transducer_axes

    return transducer_axes(experiment_setups(setup.pose_config, seed)[0].T_true["centre"])


def _centre_rotation(setup, seed):
    from histostudy.study.pose.experiments import experiment_setups

    return experiment_setups(setup.pose_config, seed)[0].T_true["centre"][:3, :3]


@pytest.mark.slow
def test_targeting_budget_baseline_is_the_study_and_registration_is_read_through(models):
    setup = _setup(models, ("registration",))
    configurations = [("baseline", setup.lab.model.off()), ("only registration", setup.lab.model)]
    records = run_error_budget(setup, seed=8, configurations=configurations, studies=("targeting",))
    records = records.set_index("configuration")
    assert records["ok"].all(), records["failure"].tolist()
    seq = np.random.SeedSequence(8).spawn(1)[0]
    row = run_targeting_experiment(setup.targeting_config, seq, pose_model=setup.pose_model,
                                   render_model=setup.render_model, physical=setup.lab.study_physical,
                                   views=VIEWS, robot_factory=sim_robot(setup.targeting_config))
    for column in ("err_euclidean", "radius_err_mm", *(f"err_{d}" for d in DIRS)):
        assert records.loc["baseline", column] == pytest.approx(row[column], abs=1e-12), column
    T = setup.lab.experiment(10_000).T_cbct_carm
    target = np.array([row[f"target_{a}"] for a in "xyz"])
    centroid = np.array([row[f"centroid_{a}"] for a in "xyz"])
    command_shift = T[:3, :3] @ target + T[:3, 3] - target  # the robot goes where the CBCT says the target is
    expected = np.linalg.norm(T[:3, :3] @ (centroid + command_shift - target))
    assert abs(expected - row["err_euclidean"]) > 1e-3
    assert records.loc["only registration", "err_euclidean"] == pytest.approx(expected, abs=1e-9)


def test_measured_reference_and_zone_apply_the_draw(models):
    setup = _setup(models, ("annotation",))
    draw = setup.lab.experiment(0)
    import pandas as pd

    reference = pd.DataFrame([{"centroid_x": 1.0, "centroid_y": 2.0, "centroid_z": 3.0, "sphere_x": 1.0,
                               "sphere_y": 2.0,
                               "sphere_z": 3.0, "sphere_radius_mm": 10.0, "ref_radius_depth": 10.0,
                               "ref_radius_tb": 10.0, "ref_radius_lr": 10.0}])
    read = measured_reference(reference, draw)
    assert np.allclose(read[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float)[0],
                       np.array([1.0, 2.0, 3.0]) + draw.annotation_centroid_mm)
    assert read["ref_radius_lr"].iloc[0] == pytest.approx(10.0 + draw.annotation_radius_mm[2])
    row = {"target_x": 0.0, "target_y": 0.0, "target_z": 0.0, "centroid_x": 0.0, "centroid_y": 0.0, "centroid_z": 1.0,
           "radius_err_mm": 0.2, **{f"axis_{d}_{a}": float(i == j) for i, d in enumerate(DIRS) for j,
                                    a in enumerate("xyz")}}
    zone = measured_zone(row, draw)
    err = np.array([0.0, 0.0, 1.0]) + draw.annotation_centroid_mm
    assert zone["err_euclidean"] == pytest.approx(np.linalg.norm(err))
    assert [zone[f"err_{d}"] for d in DIRS] == pytest.approx(list(err))
    with pytest.raises(ValueError, match="studies"):
        run_error_budget(setup, seed=1, studies=("calibration",))
    with pytest.raises(ValueError, match="baseline"):
        run_error_budget(setup, seed=1, configurations=[("lab", setup.lab.model)])
    with pytest.raises(ValueError, match="bubble_offset_mm must be zeros"):
        BudgetSetup(setup.lab, dataclasses.replace(setup.pose_config, bubble_offset_mm=(0.0, 0.0, 1.0)),
                    setup.targeting_config, setup.pose_model, setup.render_model)
