"""Tests of histostudy.study.pose._reference: the post-treatment CBCT reference (§II-D, §II-E.3) and
Table II measured against it."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import Anatomy, PhantomSpec, phantom_mask, phantom_volume, random_background
from histostudy.study.pose.experiments import PoseStudyConfig, experiment_setups
from histostudy.study.pose.geometry import DIRECTIONS, MARGINS, bubble_cloud_centre_mm, transducer_axes
from histostudy.study.pose.metrics import experiment_metrics, reference_error_summary, table2
from histostudy.study.pose.reference import cbct_reference, phantom_and_mask, phantom_placement
from histostudy.transducer import TransducerModel

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
    bias = dict(zip(DIRECTIONS, (0.0, 0.0, 0.0) if bias is None else bias))
    rows = []
    for exp in experiment_setups(config, seed):
        axes = transducer_axes(exp.T_centre)
        shift = sum(bias[d] * axes[d] for d in DIRECTIONS)
        for position, T in exp.T_true.items():
            truth = bubble_cloud_centre_mm(physical, T, config.bubble_offset_mm)
            pred = truth + shift
            if position != "centre":
                d, sign = MARGINS[position]
                pred = pred + sign * stretch * axes[d]
            err = pred - truth
            rows.append({"experiment": exp.experiment, "radius_mm": exp.radius_mm, "position": position,
                         "mode": "paper", "maps": "occlusion_aware", **{f"true_{a}": v for a, v in zip("xyz", truth)},
                         **{f"pred_{a}": v for a, v in zip("xyz", pred)},
                         **{f"err_{d}": float(err @ axes[d]) for d in DIRECTIONS},
                         "err_euclidean": float(np.linalg.norm(err)), "ok": True})
    return pd.DataFrame(rows)


def test_phantom_placement_follows_the_scene():
    scene = random_background(np.random.default_rng(4), "phantom")
    spec, T = phantom_placement(scene)
    assert spec.size_mm == scene.meta["phantom_edge_mm"] and spec.layer_thickness_mm == scene.meta["layer_mm"]
    np.testing.assert_allclose(T[:3, 3], scene.meta["phantom_center_mm"])
    np.testing.assert_allclose(T[:3, :3] @ [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], atol=1e-12)  # layers stacked upwards
    spec, T = phantom_placement(Anatomy((), kind="custom"), centre_mm=(1.0, 2.0, 3.0))
    assert spec == PhantomSpec() and np.allclose(T[:3, 3], [1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="scene"):
        phantom_placement("phantom")


def test_noise_free_cbct_reference_finds_the_true_centre_and_radius(physical_model):
    config = PoseStudyConfig(n_experiments=2, robot_repeatability_mm=0.0)
    ref = cbct_reference(config, physical=physical_model, seed=3, cbct_blur_mm=0.0, cbct_noise_hu=0.0, **COARSE)
    assert list(ref["experiment"]) == [0, 1] and ref["ok"].all()
    setups = experiment_setups(config, 3)
    for (_, row), exp in zip(ref.iterrows(), setups):
        truth = bubble_cloud_centre_mm(physical_model, exp.T_true["centre"], (0.0, 0.0, 0.0))
        np.testing.assert_allclose(row[["true_x", "true_y", "true_z"]].to_numpy(float), truth)
        # Within a fraction of the 1 mm voxel: the centroid of the zone is the true centre.
        assert row["ref_err_euclidean"] < 0.35, row["ref_err_euclidean"]
        # The zone (the union of 3x3x6 mm clouds filling the sphere, segmented) reads up to ~1 mm small.
        for d in DIRECTIONS:
            assert -1.5 < row[f"ref_radius_err_{d}"] < 0.3, (d, row[f"ref_radius_err_{d}"])
        assert abs(row["sphere_radius_mm"] - exp.radius_mm) < 1.2 and row["clearance_mm"] > 4.0
        axes = transducer_axes(exp.T_centre)
        for d in DIRECTIONS:
            np.testing.assert_allclose(row[[f"axis_{d}_{a}" for a in "xyz"]].to_numpy(float), axes[d])


def test_cbct_reference_follows_the_bubble_cloud_offset(physical_model):
    """A 2 mm offset of the bubble cloud along the transducer's +z (towards it: -depth) moves the
    treated zone with it: the reference centre follows the physical bubble cloud."""
    config = PoseStudyConfig(n_experiments=1, bubble_offset_mm=(0.0, 0.0, 2.0))
    ref = cbct_reference(config, physical=physical_model, seed=3, **COARSE).iloc[0]
    plain = cbct_reference(replace(config, bubble_offset_mm=(0.0, 0.0, 0.0)), physical=physical_model,
                                 seed=3, **COARSE).iloc[0]
    shift = ref[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float) \
        - plain[["centroid_x", "centroid_y", "centroid_z"]].to_numpy(float)
    depth = ref[["axis_depth_x", "axis_depth_y", "axis_depth_z"]].to_numpy(float)
    assert shift @ depth == pytest.approx(-2.0, abs=0.3)
    assert ref["ref_err_euclidean"] < 0.4


def test_table2_against_the_cbct_reference_shows_a_known_bias(physical_model):
    config = PoseStudyConfig(n_experiments=2)
    bias = (0.4, -0.3, 0.8)  # depth, TB, LR (mm)
    records = records_from_setups(config, 5, physical_model, bias=bias)
    ref = cbct_reference(config, physical=physical_model, seed=5, records=records, **COARSE)
    truth_metrics = experiment_metrics(records)
    cbct_metrics = experiment_metrics(records, reference=ref)
    assert set(truth_metrics["reference"]) == {"truth"} and set(cbct_metrics["reference"]) == {"cbct"}
    _, truth_values = table2(truth_metrics, "paper")
    _, cbct_values = table2(cbct_metrics, "paper")
    for d, b in zip(DIRECTIONS, bias):
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
        table2(pd.concat([truth_metrics, cbct_metrics]), "paper")


def test_a_radial_stretch_against_the_cbct_reference_is_the_stretch_plus_the_zone_radius_error(physical_model):
    config = PoseStudyConfig(n_experiments=1)
    records = records_from_setups(config, 5, physical_model, stretch=0.5)
    ref = cbct_reference(config, physical=physical_model, seed=5, records=records, **COARSE)
    metrics = experiment_metrics(records, reference=ref).iloc[0]
    for d in DIRECTIONS:
        assert metrics[f"radius_{d}"] == pytest.approx(metrics["radius_mm"] + 0.5, abs=0.05)  # 0.01 mm robot noise
        assert metrics[f"radius_err_{d}"] == pytest.approx(abs(metrics[f"radius_{d}"] - ref[f"ref_radius_{d}"].iloc[0]))


def test_cbct_reference_refuses_bad_arguments(physical_model):
    config = PoseStudyConfig(n_experiments=1)
    records = records_from_setups(config, 5, physical_model)
    with pytest.raises(ValueError, match="do not match"):
        cbct_reference(config, physical=physical_model, seed=6, records=records, **COARSE)
    with pytest.raises(ValueError, match="beyond config.n_experiments"):
        cbct_reference(config, physical=physical_model, seed=5,
                             records=records.assign(experiment=3), **COARSE)
    with pytest.raises(ValueError, match="records must be"):
        cbct_reference(config, physical=physical_model, seed=5, records=records.drop(columns="true_x"))
    with pytest.raises(ValueError, match="cbct_voxel_mm"):
        cbct_reference(config, physical=physical_model, seed=5, cbct_voxel_mm=0.0)
    with pytest.raises(ValueError, match="cbct_noise_hu"):
        cbct_reference(config, physical=physical_model, seed=5, cbct_noise_hu=-1.0)
    with pytest.raises(TypeError, match="physical"):
        cbct_reference(config, physical=None, seed=5)
    ref = cbct_reference(config, physical=physical_model, seed=5, **COARSE)
    with pytest.raises(ValueError, match="lacks the columns"):
        experiment_metrics(records, reference=ref.drop(columns="sphere_radius_mm"))
    with pytest.raises(ValueError, match="no row for experiment 1"):
        experiment_metrics(pd.concat([records, records.assign(experiment=1)]), reference=ref)
    with pytest.raises(TypeError, match="reference"):
        experiment_metrics(records, reference="cbct")
    summary = reference_error_summary(ref)
    assert len(summary) == 8 and summary["mm"].str.contains("±").all()


def test_the_phantom_is_rasterised_once_per_placement_and_read_only():
    """The configurations of an experiment treat the same phantom: the second call returns the
    first's arrays (made once), equal to phantom_volume's and phantom_mask's; nobody can write them."""
    spec = PhantomSpec(size_mm=40.0, layer_thickness_mm=5.0)
    T = make_transform(rotation_about_axis([0.0, 0.0, 1.0], 0.3), [1.0, -2.0, 3.0])
    phantom, mask = phantom_and_mask(spec, T, 1.0)
    again, mask_again = phantom_and_mask(spec, T.copy(), 1.0)
    assert again is phantom and mask_again is mask
    np.testing.assert_array_equal(phantom.data, phantom_volume(spec, T, spacing_mm=1.0).data)
    np.testing.assert_array_equal(mask, phantom_mask(phantom_volume(spec, T, spacing_mm=1.0), spec, T))
    with pytest.raises(ValueError, match="read-only"):
        phantom.data[0, 0, 0] = 0.0
    moved = T.copy()
    moved[0, 3] += 1.0
    assert phantom_and_mask(spec, moved, 1.0)[0] is not phantom
