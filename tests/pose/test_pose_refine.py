"""Tests of histostudy.pose.refine: Nelder-Mead (the paper's) and Levenberg-Marquardt recover a known
pose on two views from a few-degree / few-mm perturbation."""

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_angle
from histostudy.imaging import default_biplane, render_labels
from histostudy.pose import (
    DistanceMaps,
    PoseCost,
    apply_left_perturbation,
    refine_levenberg_marquardt,
    refine_nelder_mead,
)
from histostudy.pose.refine import RefineResult
from histostudy.transducer import FEATURE_CLASSES, TransducerModel, pose_facing

T_TRUE = pose_facing(focal_point_mm=(5.0, -3.0, 8.0), axial_rotation_rad=0.3)


@pytest.fixture(scope="module")
def setup():
    views = default_biplane()
    fine = TransducerModel.build(spacing_mm=0.25)
    model = TransducerModel.build(spacing_mm=0.47)
    # Noise-free masks, each class rasterised alone (the overlap priority of the label image would
    # hide parts of the lower classes and bias the optimum; see test_priority_labels_...).
    maps = [DistanceMaps(v, {f: render_labels(fine.only(f), T_TRUE, v) == int(f) for f in FEATURE_CLASSES})
            for v in views]
    return {"views": views, "fine": fine, "model": model, "cost": PoseCost(model.points, maps)}


def perturbed(seed, angle_deg=3.0, shift_mm=4.0):
    rng = np.random.default_rng(seed)
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    delta = np.r_[axis / np.linalg.norm(axis) * np.deg2rad(angle_deg), direction / np.linalg.norm(direction) * shift_mm]
    return apply_left_perturbation(T_TRUE, delta)


def errors(T):
    """(focal-point error mm, rotation error deg) against the truth."""
    return (float(np.linalg.norm(T[:3, 3] - T_TRUE[:3, 3])),
            float(np.rad2deg(rotation_angle(T[:3, :3].T @ T_TRUE[:3, :3]))))


def test_nelder_mead_recovers_the_pose_from_a_3_deg_4_mm_perturbation(setup):
    cost = setup["cost"]
    T0 = perturbed(10)
    assert errors(T0)[0] == pytest.approx(4.0)
    res = refine_nelder_mead(cost, T0)
    assert isinstance(res, RefineResult) and res.method == "nelder-mead"
    focal, rot = errors(res.T)
    assert focal < 0.06 and rot < 0.05, (focal, rot)
    assert res.converged and res.iterations < 1000 and res.evaluations >= res.iterations
    assert res.cost == pytest.approx(cost(res.T)) and res.cost <= cost(T_TRUE) + 0.01
    np.testing.assert_array_equal(res.focal_point_mm, res.T[:3, 3])


@pytest.mark.parametrize("seed", [11, 12])
def test_levenberg_marquardt_recovers_the_pose(setup, seed):
    cost = setup["cost"]
    T0 = perturbed(seed, angle_deg=2.5, shift_mm=5.0)
    res = refine_levenberg_marquardt(cost, T0)
    focal, rot = errors(res.T)
    assert focal < 0.06 and rot < 0.05, (focal, rot)
    assert res.converged and res.method == "levenberg-marquardt", res.message
    assert res.cost == pytest.approx(cost(res.T)) and res.cost < cost(T_TRUE)


def test_levenberg_marquardt_coarse_to_fine_and_warm_start(setup):
    cost = setup["cost"]
    coarse = cost.subset(2000, np.random.default_rng(0))
    res = refine_levenberg_marquardt(cost, perturbed(13), coarse=coarse)
    focal, rot = errors(res.T)
    assert focal < 0.06 and rot < 0.05, (focal, rot)
    assert res.info["coarse"]["n_points"] == coarse.n_total and res.info["coarse"]["iterations"] >= 1
    # Tracking: restarting from the converged pose stops at once, where it is.
    again = refine_levenberg_marquardt(cost, res.T, damping=res.info["damping"])
    assert again.iterations <= 3 and again.converged
    assert errors(again.T)[0] < 0.06


def test_priority_labels_bias_the_optimum_only_slightly(setup):
    """With the overlap-priority label image (what a segmentation gives), hidden parts of the lower
    classes pull the optimum off the truth by a fraction of a pixel (~0.1 mm here)."""
    maps = [DistanceMaps(v, render_labels(setup["fine"], T_TRUE, v)) for v in setup["views"]]
    cost = PoseCost(setup["model"].points, maps)
    res = refine_levenberg_marquardt(cost, perturbed(14))
    focal, rot = errors(res.T)
    assert focal < 0.25 and rot < 0.1, (focal, rot)


def test_nelder_mead_parameters_are_degrees_and_mm_about_the_initial_pose():
    """On a smooth bowl the simplex reaches the optimum to the tolerances in their stated units."""
    target = make_transform(pose_facing((1.0, 2.0, 3.0))[:3, :3], (10.0, -5.0, 2.0))

    def bowl(T):
        return np.rad2deg(rotation_angle(T[:3, :3].T @ target[:3, :3])) ** 2 + np.sum((T[:3, 3] - target[:3, 3]) ** 2)

    T0 = apply_left_perturbation(target, [0.04, -0.03, 0.02, 3.0, -2.0, 1.0])
    res = refine_nelder_mead(bowl, T0, xatol=1e-4, fatol=1e-8)
    assert res.converged
    assert np.linalg.norm(res.T[:3, 3] - target[:3, 3]) < 1e-3
    assert np.rad2deg(rotation_angle(res.T[:3, :3].T @ target[:3, :3])) < 1e-3
    # The initial simplex is initial_step wide: the first evaluations are 2 deg / 2 mm away.
    assert res.info["x"].shape == (6,)


def test_bad_arguments_raise(setup):
    cost = setup["cost"]
    with pytest.raises(ValueError, match="initial_step"):
        refine_nelder_mead(cost, T_TRUE, initial_step=(0.0, 2.0))
    with pytest.raises(ValueError, match="max_iter"):
        refine_nelder_mead(cost, T_TRUE, max_iter=0)
    with pytest.raises(ValueError, match="T_init must be a 4x4"):
        refine_nelder_mead(cost, np.eye(3))
    with pytest.raises(TypeError, match="cost must be a histostudy.pose.cost.PoseCost"):
        refine_levenberg_marquardt(lambda T: 0.0, T_TRUE)
    with pytest.raises(ValueError, match="xtol_mm"):
        refine_levenberg_marquardt(cost, T_TRUE, xtol_mm=-1.0)
