"""Tests of histostudy.study.pose_estimation: Table II's arithmetic on records with known errors,
the margin geometry, and one small experiment end to end."""

import numpy as np
import pandas as pd
import pytest

from histostudy.carm import default_biplane
from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.study import pose_estimation as study
from histostudy.transducer import TransducerModel, pose_facing

T_CENTRE = pose_facing((0.1, 1.0, -0.2), focal_point_mm=(3.0, -2.0, 5.0), axial_rotation_rad=0.4)


def test_transducer_axes_are_orthonormal_and_depth_is_propagation():
    axes = study.transducer_axes(T_CENTRE)
    M = np.stack([axes[d] for d in study.DIRECTIONS])
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
    # Depth points from the transducer (+z side) towards the focal point: along -z.
    np.testing.assert_allclose(axes["depth"], -T_CENTRE[:3, 2], atol=1e-12)


def test_margin_positions_are_r_away_along_each_axis_with_the_same_rotation():
    positions = study.margin_positions(T_CENTRE, 12.5)
    assert set(positions) == {"centre", "top", "bottom", "left", "right", "front", "back"}
    axes = study.transducer_axes(T_CENTRE)
    for name, (direction, sign) in study.MARGINS.items():
        T = positions[name]
        np.testing.assert_allclose(T[:3, :3], T_CENTRE[:3, :3])
        np.testing.assert_allclose(T[:3, 3] - T_CENTRE[:3, 3], sign * 12.5 * axes[direction], atol=1e-12)


def synthetic_records(offsets: dict, radius: float = 10.0, experiment: int = 0) -> pd.DataFrame:
    """Records whose prediction = truth + offsets[position] (world mm), for one experiment."""
    rows = []
    for position, T in study.margin_positions(T_CENTRE, radius).items():
        truth = T[:3, 3]
        pred = truth + np.asarray(offsets.get(position, np.zeros(3)))
        axes = study.transducer_axes(T_CENTRE)
        err = pred - truth
        rows.append({"experiment": experiment, "radius_mm": radius, "position": position, "mode": "paper",
                     "maps": "occlusion_aware", **{f"true_{a}": v for a, v in zip("xyz", truth)},
                     **{f"pred_{a}": v for a, v in zip("xyz", pred)},
                     **{f"err_{d}": float(err @ axes[d]) for d in study.DIRECTIONS},
                     "err_euclidean": float(np.linalg.norm(err)), "ok": True})
    return pd.DataFrame(rows)


def test_table2_of_a_pure_shift_is_the_shift_in_the_centre_and_nothing_in_the_radius():
    axes = study.transducer_axes(T_CENTRE)
    shift = 0.3 * axes["depth"] - 0.4 * axes["lr"]
    records = synthetic_records({p: shift for p in ["centre", *study.MARGINS]})
    metrics = study.experiment_metrics(records)
    row = metrics.iloc[0]
    assert row["centre_err_depth"] == pytest.approx(0.3) and row["centre_err_lr"] == pytest.approx(-0.4)
    assert row["centre_err_tb"] == pytest.approx(0.0, abs=1e-12)
    assert row["centre_err_euclidean"] == pytest.approx(0.5)
    # Opposite margins shift together: the predicted radius is exact and the precision is zero.
    for d in study.DIRECTIONS:
        assert row[f"radius_err_{d}"] == pytest.approx(0.0, abs=1e-12)
    assert row["precision"] == pytest.approx(0.0, abs=1e-12)
    # Margin error: distance of each shifted margin point to the reference sphere's surface.
    top = np.linalg.norm(10.0 * axes["tb"] + shift) - 10.0
    assert row["margin_err_top"] == pytest.approx(abs(top))
    table, values = study.table2(metrics, "paper")
    assert values["table2.center_bias.depth"][0] == pytest.approx(0.3)
    assert values["table2.center_mae.lr"][0] == pytest.approx(0.4)
    assert values["table2.center_mae.overall"][0] == pytest.approx(0.5)
    assert list(table.columns) == ["", "Depth", "TB", "LR", "Overall"]
    assert table.loc[0, "Overall"] == "N/A"  # the paper has no overall bias either


def test_table2_of_a_radial_stretch_is_the_radius_error():
    axes = study.transducer_axes(T_CENTRE)
    offsets = {name: sign * 0.25 * axes[d] for name, (d, sign) in study.MARGINS.items()}
    metrics = study.experiment_metrics(synthetic_records(offsets, radius=12.5))
    row = metrics.iloc[0]
    for d in study.DIRECTIONS:
        assert row[f"radius_{d}"] == pytest.approx(12.75)
        assert row[f"radius_err_{d}"] == pytest.approx(0.25)
        assert row[f"margin_err_{d}"] == pytest.approx(0.25)
    assert row["centre_err_euclidean"] == 0.0 and row["precision"] == pytest.approx(0.0, abs=1e-12)


def test_table2_mean_and_sd_are_over_experiments():
    axes = study.transducer_axes(T_CENTRE)
    records = pd.concat([synthetic_records({"centre": b * axes["tb"]}, experiment=e)
                         for e, b in enumerate([0.2, -0.6, 1.0])])
    _, values = study.table2(study.experiment_metrics(records), "paper")
    mean, sd = values["table2.center_bias.tb"]
    assert mean == pytest.approx(np.mean([0.2, -0.6, 1.0])) and sd == pytest.approx(np.std([0.2, -0.6, 1.0], ddof=1))
    assert values["table2.center_mae.tb"][0] == pytest.approx(0.6)
    with pytest.raises(ValueError, match="no experiment metrics for mode='fast'"):
        study.table2(study.experiment_metrics(records), "fast")


def test_axial_symmetric_rotation_error_ignores_the_half_turn_only():
    half_turn = make_transform(np.diag([-1.0, -1.0, 1.0]))
    assert study.axial_symmetric_rotation_error_deg(T_CENTRE @ half_turn, T_CENTRE) == pytest.approx(0.0, abs=1e-6)
    tilt = make_transform(matrix_from_rotvec([np.deg2rad(3.0), 0.0, 0.0]))
    assert study.axial_symmetric_rotation_error_deg(T_CENTRE @ tilt, T_CENTRE) == pytest.approx(3.0)
    quarter = make_transform(matrix_from_rotvec([0.0, 0.0, np.pi / 2]))
    assert study.axial_symmetric_rotation_error_deg(T_CENTRE @ quarter, T_CENTRE) == pytest.approx(90.0)


def test_random_poses_keep_the_given_points_in_every_view():
    views = default_biplane()
    rng = np.random.default_rng(0)
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 120.0]])
    for _ in range(10):
        T = study.random_pose_in_views(rng, views, visible_points_mm=points)
        world = points @ T[:3, :3].T + T[:3, 3]
        assert np.all(np.abs(T[:3, 3]) <= 100.0)
        for v in views:
            assert np.all(v.in_image(v.project(world)))
    with pytest.raises(RuntimeError, match="no pose"):
        study.random_pose_in_views(rng, views, visible_points_mm=[[0.0, 0.0, 5000.0]], max_tries=20)


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="n_experiments"):
        study.PoseStudyConfig(n_experiments=0)
    with pytest.raises(ValueError, match="margin_mm"):
        study.PoseStudyConfig(margin_mm=(10.0, -1.0))
    with pytest.raises(ValueError, match="modes"):
        study.PoseStudyConfig(modes=("gradient",))
    with pytest.raises(ValueError, match="distance_maps"):
        study.PoseStudyConfig(distance_maps=("chamfer",))
    assert study.PoseStudyConfig(modes=("paper", "fast"), distance_maps=("occlusion_aware", "per_class")).variants == [
        ("paper", "occlusion_aware"), ("paper", "per_class"), ("fast", "occlusion_aware"), ("fast", "per_class")]


@pytest.mark.slow
def test_one_small_experiment_end_to_end():
    """Coarse rendering (0.47 mm, 2 splats) and the fast mode: every position estimated, errors
    well inside a millimetre, and the metrics computed from the rows."""
    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    config = study.PoseStudyConfig(n_experiments=1, modes=("fast",), n_splats=2, track=True)
    records = study.run_pose_study(config, pose_model=model, render_model=model, physical=physical,
                                   views=default_biplane(), seed=11)
    full = records[records["mode"] == "fast"]
    assert len(full) == 7 and set(records["mode"]) == {"fast", "track"}
    assert full["ok"].all(), full["failure"].tolist()
    assert full["err_euclidean"].max() < 1.0, full["err_euclidean"].tolist()
    metrics = study.experiment_metrics(records)
    assert len(metrics) == 1 and metrics["radius_err_overall"].iloc[0] < 0.5
    summary = study.tracking_summary(records)
    assert summary["n"] == 6 and summary["track_error_mm"][0] < 1.0
    timing = study.stage_timing(records)
    assert set(timing["mode"]) == {"fast", "track"} and (timing["total"] > 0).all()


@pytest.mark.slow
def test_noise_sweep_renders_each_dose_and_the_oracle_ignores_the_image():
    from histostudy.orientation import OracleOrientation
    from histostudy.segment import OracleSegmenter

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    config = study.PoseStudyConfig(n_splats=1)
    table = study.noise_sweep([2e3, 5e4], pose_model=model, render_model=model, physical=physical,
                              views=default_biplane(), seed=5, config=config, segmenter=OracleSegmenter(),
                              orientation=OracleOrientation(), n_poses=1)
    assert list(table["photons_per_pixel"]) == [2e3, 5e4] and table["ok"].all()
    # The oracle reads the labels, not the image: the same error at every dose.
    assert table["error_mm"].nunique() == 1 and table["error_mm"].iloc[0] < 1.0
    with pytest.raises(ValueError, match="photons_per_pixel"):
        study.noise_sweep([0.0], pose_model=model, render_model=model, physical=physical, views=default_biplane(),
                          seed=5, config=config, segmenter=OracleSegmenter())
