"""Tests of histostudy.study.pose_estimation: Table II's arithmetic on records with known errors,
the margin geometry, the post-treatment CBCT reference, and one small experiment end to end."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import Anatomy, PhantomSpec, default_biplane, random_background
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
    with pytest.raises(ValueError, match="degradation must be one of"):
        study.PoseStudyConfig(degradation="unet")
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
    from histostudy.learning import OracleOrientation
    from histostudy.learning import OracleSegmenter

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


@pytest.mark.slow
def test_robustness_sweep_runs_the_stages_it_is_given():
    from histostudy.learning import OracleOrientation
    from histostudy.learning import OracleSegmenter

    class CountingSegmenter:
        def __init__(self):
            self.calls = 0

        def segment(self, frame, rng=None):
            self.calls += 1
            return OracleSegmenter().segment(frame, rng)

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    segmenter = CountingSegmenter()
    table = study.robustness_sweep(1, pose_model=model, render_model=model, physical=physical,
                                   views=default_biplane(), seed=5, config=study.PoseStudyConfig(n_splats=1),
                                   inits=("robust",), segmenter=segmenter, orientation=OracleOrientation())
    assert segmenter.calls == 2 and list(table["init"]) == ["robust"]
    assert table["success"].all() and table["error_mm"].iloc[0] < 1.0


def test_robustness_summary_counts_refusals_and_wrong_accepted_poses():
    robust = pd.DataFrame({
        "pose": [0, 1, 2, 3, 0, 1], "init": ["robust"] * 4 + ["paper"] * 2,
        "verdict_ok": [True, True, False, True, True, False], "success": [True, False, False, True, True, False],
        "error_mm": [0.5, 41.0, np.nan, 0.3, 0.7, np.nan], "seconds": [1.0, 3.0, 4.0, 2.0, 1.0, 5.0]})
    summary = study.robustness_summary(robust).set_index("init")
    assert summary.loc["robust", "poses"] == 4 and summary.loc["robust", "success_rate"] == 0.5
    assert summary.loc["robust", "refused"] == 1 and summary.loc["robust", "wrong_accepted"] == 1
    assert summary.loc["robust", "median_error_mm"] == 0.5 and summary.loc["robust", "median_seconds"] == 2.5
    assert (summary.loc["paper", "refused"], summary.loc["paper", "wrong_accepted"]) == (1, 0)
    with pytest.raises(ValueError, match=r"missing columns \['verdict_ok'\]"):
        study.robustness_summary(robust.drop(columns="verdict_ok"))


# --- The post-treatment CBCT reference (§II-D, §II-E.3) ---------------------------------------------

#: Coarse and fast: a 0.75 mm phantom (1 mm lets the 3x3x6 mm clouds alias by up to 0.6 mm) and a 1 mm CBCT,
#: ~0.5 s per experiment.
COARSE = dict(phantom_voxel_mm=0.75, cbct_voxel_mm=1.0)


@pytest.fixture(scope="module")
def physical_model():
    return TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(3))


def records_from_setups(config, seed, physical, bias=None, stretch=0.0):
    """run_pose_study-like rows for the redrawn set-ups whose predictions are the true bubble-cloud
    centres moved by ``bias`` (depth, TB, LR components, mm) and, for the margins, pushed outwards by
    ``stretch`` mm along their direction; no rendering."""
    bias = dict(zip(study.DIRECTIONS, (0.0, 0.0, 0.0) if bias is None else bias))
    rows = []
    for exp in study.experiment_setups(config, seed):
        axes = study.transducer_axes(exp.T_centre)
        shift = sum(bias[d] * axes[d] for d in study.DIRECTIONS)
        for position, T in exp.T_true.items():
            truth = study._bubble_centre(physical, T, config.bubble_offset_mm)
            pred = truth + shift
            if position != "centre":
                d, sign = study.MARGINS[position]
                pred = pred + sign * stretch * axes[d]
            err = pred - truth
            rows.append({"experiment": exp.experiment, "radius_mm": exp.radius_mm, "position": position,
                         "mode": "paper", "maps": "occlusion_aware", **{f"true_{a}": v for a, v in zip("xyz", truth)},
                         **{f"pred_{a}": v for a, v in zip("xyz", pred)},
                         **{f"err_{d}": float(err @ axes[d]) for d in study.DIRECTIONS},
                         "err_euclidean": float(np.linalg.norm(err)), "ok": True})
    return pd.DataFrame(rows)


def test_experiment_setups_keep_the_study_draws():
    """Drawing the CBCT stream (child 5) changes none of run_pose_study's draws (children 0-4)."""
    config = study.PoseStudyConfig(n_experiments=2)
    setups = study.experiment_setups(config, 7)
    assert [s.experiment for s in setups] == [0, 1]
    for exp, seq in zip(setups, np.random.SeedSequence(7).spawn(2)):
        rng_pose, rng_scene, _, rng_robot, _ = (np.random.default_rng(s) for s in seq.spawn(5))
        radius = float(rng_pose.choice(config.margin_mm))
        scene = random_background(rng_scene, config.background)
        T_centre = study._experiment_pose(rng_pose, config, scene.meta["phantom_center_mm"])
        assert exp.radius_mm == radius
        np.testing.assert_array_equal(exp.T_centre, T_centre)
        for position, T_nominal in study.margin_positions(T_centre, radius).items():
            expected = T_nominal.copy()
            expected[:3, 3] += rng_robot.normal(0, config.robot_repeatability_mm, 3)
            np.testing.assert_array_equal(exp.T_true[position], expected)


def test_phantom_placement_follows_the_scene():
    scene = random_background(np.random.default_rng(4), "phantom")
    spec, T = study.phantom_placement(scene)
    assert spec.size_mm == scene.meta["phantom_edge_mm"] and spec.layer_thickness_mm == scene.meta["layer_mm"]
    np.testing.assert_allclose(T[:3, 3], scene.meta["phantom_center_mm"])
    np.testing.assert_allclose(T[:3, :3] @ [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], atol=1e-12)  # layers stacked upwards
    spec, T = study.phantom_placement(Anatomy((), kind="custom"), centre_mm=(1.0, 2.0, 3.0))
    assert spec == PhantomSpec() and np.allclose(T[:3, 3], [1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="scene"):
        study.phantom_placement("phantom")


def test_noise_free_cbct_reference_finds_the_true_centre_and_radius(physical_model):
    config = study.PoseStudyConfig(n_experiments=2, robot_repeatability_mm=0.0)
    ref = study.cbct_reference(config, physical=physical_model, seed=3, cbct_blur_mm=0.0, cbct_noise_hu=0.0, **COARSE)
    assert list(ref["experiment"]) == [0, 1] and ref["ok"].all()
    setups = study.experiment_setups(config, 3)
    for (_, row), exp in zip(ref.iterrows(), setups):
        truth = study._bubble_centre(physical_model, exp.T_true["centre"], (0.0, 0.0, 0.0))
        np.testing.assert_allclose(row[["true_x", "true_y", "true_z"]].to_numpy(float), truth)
        # Within a fraction of the 1 mm voxel: the centroid of the zone is the true centre.
        assert row["ref_err_euclidean"] < 0.35, row["ref_err_euclidean"]
        # The zone (the union of 3x3x6 mm clouds filling the sphere, segmented) reads up to ~1 mm small.
        for d in study.DIRECTIONS:
            assert -1.5 < row[f"ref_radius_err_{d}"] < 0.3, (d, row[f"ref_radius_err_{d}"])
        assert abs(row["sphere_radius_mm"] - exp.radius_mm) < 1.2 and row["clearance_mm"] > 4.0
        axes = study.transducer_axes(exp.T_centre)
        for d in study.DIRECTIONS:
            np.testing.assert_allclose(row[[f"axis_{d}_{a}" for a in "xyz"]].to_numpy(float), axes[d])


def test_cbct_reference_follows_the_bubble_cloud_offset(physical_model):
    """A 2 mm offset of the bubble cloud along the transducer's +z (towards it: -depth) moves the
    treated zone with it: the reference centre follows the physical bubble cloud."""
    config = study.PoseStudyConfig(n_experiments=1, bubble_offset_mm=(0.0, 0.0, 2.0))
    ref = study.cbct_reference(config, physical=physical_model, seed=3, **COARSE).iloc[0]
    plain = study.cbct_reference(replace(config, bubble_offset_mm=(0.0, 0.0, 0.0)), physical=physical_model,
                                 seed=3, **COARSE).iloc[0]
    shift = ref[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float) \
        - plain[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float)
    depth = ref[["axis_depth_x", "axis_depth_y", "axis_depth_z"]].to_numpy(float)
    assert shift @ depth == pytest.approx(-2.0, abs=0.3)
    assert ref["ref_err_euclidean"] < 0.4


def test_table2_against_the_cbct_reference_shows_a_known_bias(physical_model):
    config = study.PoseStudyConfig(n_experiments=2)
    bias = (0.4, -0.3, 0.8)  # depth, TB, LR (mm)
    records = records_from_setups(config, 5, physical_model, bias=bias)
    ref = study.cbct_reference(config, physical=physical_model, seed=5, records=records, **COARSE)
    truth_metrics = study.experiment_metrics(records)
    cbct_metrics = study.experiment_metrics(records, reference=ref)
    assert set(truth_metrics["reference"]) == {"truth"} and set(cbct_metrics["reference"]) == {"cbct"}
    _, truth_values = study.table2(truth_metrics, "paper")
    _, cbct_values = study.table2(cbct_metrics, "paper")
    for d, b in zip(study.DIRECTIONS, bias):
        assert truth_values[f"table2.center_bias.{d}"][0] == pytest.approx(b)
        # Against the CBCT: the bias minus the reference's own error, exactly, and the bias within it.
        assert cbct_values[f"table2.center_bias.{d}"][0] == pytest.approx(b - ref[f"ref_err_{d}"].mean())
        assert cbct_values[f"table2.center_bias.{d}"][0] == pytest.approx(b, abs=0.3)
        assert cbct_values[f"table2.center_mae.{d}"][0] == pytest.approx(abs(b), abs=0.3)
        # Opposite margins move together: the radius error is the reference's radius error (up to
        # the robot's 0.01 mm repeatability noise in the true margin positions).
        np.testing.assert_allclose(cbct_metrics[f"radius_err_{d}"],
                                   np.abs(cbct_metrics[f"radius_{d}"] - ref[f"ref_radius_{d}"]), atol=1e-12)
        np.testing.assert_allclose(cbct_metrics[f"radius_err_{d}"], np.abs(ref[f"ref_radius_err_{d}"]), atol=0.05)
    assert cbct_values["table2.center_mae.overall"][0] == pytest.approx(np.linalg.norm(bias), abs=0.3)
    # The margin error is measured to the segmented zone's fitted sphere.
    row, r0 = cbct_metrics.iloc[0], ref.iloc[0]
    top = records[(records["experiment"] == 0) & (records["position"] == "top")]
    p = top[["pred_x", "pred_y", "pred_z"]].to_numpy(float)[0]
    c = r0[["sphere_x", "sphere_y", "sphere_z"]].to_numpy(float)
    assert row["margin_err_top"] == pytest.approx(abs(np.linalg.norm(p - c) - r0["sphere_radius_mm"]))
    # Precision needs no reference.
    np.testing.assert_allclose(cbct_metrics["precision"], truth_metrics["precision"])
    with pytest.raises(ValueError, match="mix references"):
        study.table2(pd.concat([truth_metrics, cbct_metrics]), "paper")


def test_a_radial_stretch_against_the_cbct_reference_is_the_stretch_plus_the_zone_radius_error(physical_model):
    config = study.PoseStudyConfig(n_experiments=1)
    records = records_from_setups(config, 5, physical_model, stretch=0.5)
    ref = study.cbct_reference(config, physical=physical_model, seed=5, records=records, **COARSE)
    metrics = study.experiment_metrics(records, reference=ref).iloc[0]
    for d in study.DIRECTIONS:
        assert metrics[f"radius_{d}"] == pytest.approx(metrics["radius_mm"] + 0.5, abs=0.05)  # 0.01 mm robot noise
        assert metrics[f"radius_err_{d}"] == pytest.approx(abs(metrics[f"radius_{d}"] - ref[f"ref_radius_{d}"].iloc[0]))


def test_cbct_reference_refuses_bad_arguments(physical_model):
    config = study.PoseStudyConfig(n_experiments=1)
    records = records_from_setups(config, 5, physical_model)
    with pytest.raises(ValueError, match="do not match"):
        study.cbct_reference(config, physical=physical_model, seed=6, records=records, **COARSE)
    with pytest.raises(ValueError, match="beyond config.n_experiments"):
        study.cbct_reference(config, physical=physical_model, seed=5,
                             records=records.assign(experiment=3), **COARSE)
    with pytest.raises(ValueError, match="records must be"):
        study.cbct_reference(config, physical=physical_model, seed=5, records=records.drop(columns="true_x"))
    with pytest.raises(ValueError, match="cbct_voxel_mm"):
        study.cbct_reference(config, physical=physical_model, seed=5, cbct_voxel_mm=0.0)
    with pytest.raises(ValueError, match="cbct_noise_hu"):
        study.cbct_reference(config, physical=physical_model, seed=5, cbct_noise_hu=-1.0)
    with pytest.raises(TypeError, match="physical"):
        study.cbct_reference(config, physical=None, seed=5)
    ref = study.cbct_reference(config, physical=physical_model, seed=5, **COARSE)
    with pytest.raises(ValueError, match="lacks the columns"):
        study.experiment_metrics(records, reference=ref.drop(columns="sphere_radius_mm"))
    with pytest.raises(ValueError, match="no row for experiment 1"):
        study.experiment_metrics(pd.concat([records, records.assign(experiment=1)]), reference=ref)
    with pytest.raises(TypeError, match="reference"):
        study.experiment_metrics(records, reference="cbct")
    summary = study.reference_error_summary(ref)
    assert len(summary) == 8 and summary["mm"].str.contains("±").all()


def test_study_stages_are_learned_when_they_meet_the_requirements_else_the_oracles():
    import types

    from histostudy.learning import OracleOrientation
    from histostudy.learning import OracleSegmenter

    config = study.PoseStudyConfig(n_experiments=1)
    good_seg = types.SimpleNamespace(manifest={"validation": {"pixel_accuracy": 0.97}, "weights_file": "u.safetensors"})
    good_vgg = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 3.0, "elevation_mae_deg": 2.0},
                                               "weights_file": "v.safetensors"})
    poor_vgg = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 45.3, "elevation_mae_deg": 15.7}})
    stages = study.study_stages(config, segmenter=good_seg, orientation=good_vgg)
    assert stages.learned and (stages.segmenter, stages.orientation) == (good_seg, good_vgg)
    assert "u.safetensors" in stages.why and "v.safetensors" in stages.why
    stages = study.study_stages(config, segmenter=good_seg, orientation=poor_vgg)
    assert not stages.learned and "45.3 deg exceeds 30.0" in stages.why
    assert isinstance(stages.segmenter, OracleSegmenter) and isinstance(stages.orientation, OracleOrientation)
    assert (stages.shipped_segmenter, stages.shipped_orientation) == (good_seg, poor_vgg)  # for the comparison
    assert stages.segmenter.degradation is not None  # the config's Table I oracle, not perfect labels
    stages = study.study_stages(config, learned=False, segmenter=good_seg, orientation=good_vgg)
    assert not stages.learned and "disabled" in stages.why
    assert stages.shipped_segmenter is None and stages.shipped_orientation is None


@pytest.mark.slow
def test_robustness_sweep_gives_the_same_rows_on_one_worker_or_two():
    from histostudy.learning import OracleOrientation

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    kwargs = dict(pose_model=model, render_model=model, physical=physical, views=default_biplane(), seed=11,
                  config=study.PoseStudyConfig(n_splats=1), inits=("robust",), orientation=OracleOrientation())
    one = study.robustness_sweep(2, **kwargs)
    two = study.robustness_sweep(2, workers=2, **kwargs)
    pd.testing.assert_frame_equal(one.drop(columns="seconds"), two.drop(columns="seconds"))
    assert {"rms_A", "body_rms_B", "unexplained_A", "disagreement_mm_B"} <= set(one.columns)
    assert one["verdict_ok"].all() and (one["error_mm"] < 2.0).all()
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        study.robustness_sweep(2, workers=0, **kwargs)
