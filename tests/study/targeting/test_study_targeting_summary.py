"""The targeting study's summaries and figures (notebook 05's tables, comparisons and figures), on
records of known values: no experiment is run."""

import inspect
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from histostudy.calibration import calibrate, calibration_sensitivity
from histostudy.study import targeting as T
from histostudy.study.pose.geometry import DIRECTIONS
from histostudy.study.targeting._positioning import target_orientation
from histostudy.study.targeting._summary import (
    SENSITIVITY_METRICS,
    calibration_sensitivity_table,
    calibration_table,
    error_table,
    first_robot_rows,
    robot_max_difference,
    sensitivity_caption,
    sensitivity_medians,
    summary,
    targeting_comparisons,
)
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth

ERR = ("err_depth", "err_tb", "err_lr", "err_euclidean", "radius_err_mm")


def records_of(robots=("sim", "rtde"), correction=True, n_experiments=2) -> pd.DataFrame:
    """Rows of known errors: experiment e has err_depth = e + 1, err_tb = -(e + 1), err_lr = 0.5,
    err_euclidean = 2 (e + 1), radius_err_mm = -0.25 (e + 1); corrected errors a tenth of those."""
    rows = []
    for e in range(n_experiments):
        for robot in robots:
            k = e + 1.0
            row = {"experiment": e, "robot": robot, "diameter_mm": 20.0, "err_depth": k, "err_tb": -k,
                   "err_lr": 0.5, "err_euclidean": 2 * k, "radius_err_mm": -0.25 * k, "n_points": 100 + e,
                   "moves": 50 + e, "cal_pose_error_mm": 0.1 * k, "cal_rms_focal_residual_mm": 0.2,
                   "cal_max_rotation_residual_deg": 0.3, "cal_X_rotation_deg": 0.4 * k, "cal_X_translation_mm": 0.5,
                   "cal_Y_rotation_deg": 0.6, "cal_Y_translation_mm": 0.7, "cal_error_at_target_mm": 0.8 * k,
                   "physical_focal_offset_mm": 0.9}
            if correction:
                row.update({f"corr_{c}": 0.1 * row[c] for c in ERR})
                row.update({f"bias_learnt_{d}": 0.01 for d in DIRECTIONS})
            rows.append(row)
    return pd.DataFrame(rows)


def test_first_robot_rows_keeps_one_row_per_experiment():
    main = first_robot_rows(records_of())
    assert list(main["robot"]) == ["sim", "sim"]
    assert list(main["experiment"]) == [0, 1]
    assert list(main.index) == [0, 1]


def test_error_and_calibration_tables_pick_their_columns():
    with_corr = error_table(records_of())
    assert list(with_corr.columns[:8]) == ["experiment", "robot", "diameter_mm", *ERR]
    assert "corr_err_euclidean" in with_corr and "bias_learnt_lr" in with_corr
    assert list(with_corr.columns[-2:]) == ["n_points", "moves"]
    without = error_table(records_of(correction=False))
    assert not any(c.startswith(("corr_", "bias_")) for c in without.columns)
    assert len(without.columns) == 10
    cal = calibration_table(records_of())
    assert all(c.startswith("cal_") for c in cal.columns[2:-1])
    assert list(cal.columns[-1:]) == ["physical_focal_offset_mm"] and len(cal) == 4


def test_robot_max_difference_is_the_largest_float_difference():
    records = records_of()
    assert robot_max_difference(records) == 0.0
    rtde = records["robot"] == "rtde"
    records.loc[rtde & (records["experiment"] == 1), "err_lr"] += 3e-7
    records.loc[rtde, "moves"] += 5  # an integer column: not compared
    records.loc[rtde & (records["experiment"] == 0), "cal_Y_translation_mm"] = np.nan  # NaN ignored
    assert robot_max_difference(records) == pytest.approx(3e-7, rel=1e-6)
    assert robot_max_difference(records_of(robots=("sim",))) is None


def test_targeting_comparisons_in_order_with_known_values():
    comparisons = targeting_comparisons(records_of())
    keys = [c["key"] for c in comparisons]
    assert keys == (["targeting.calibration_error_at_target", "targeting.calibration_rotation", "targeting.euclidean"]
                    + [f"targeting.mae.{d}" for d in DIRECTIONS] + [f"targeting.bias.{d}" for d in DIRECTIONS]
                    + ["targeting.radius_mae", "targeting.n_studies", "targeting.corrected.euclidean"]
                    + [f"targeting.corrected.bias.{d}" for d in DIRECTIONS] + ["targeting.rtde_vs_sim"])
    by_key = {c["key"]: c for c in comparisons}
    # Over the first robot's two experiments (k = 1, 2): mean and sample SD.
    assert by_key["targeting.euclidean"]["ours"] == pytest.approx((3.0, np.sqrt(2.0)))
    assert by_key["targeting.mae.tb"]["ours"] == pytest.approx((1.5, np.sqrt(0.5)))
    assert by_key["targeting.bias.tb"]["ours"] == pytest.approx(-1.5)
    assert by_key["targeting.radius_mae"]["ours"] == pytest.approx((0.375, 0.25 * np.sqrt(0.5)))
    assert by_key["targeting.calibration_error_at_target"]["ours"] == pytest.approx((1.2, 0.8 * np.sqrt(0.5)))
    assert by_key["targeting.n_studies"]["ours"] == 2
    assert by_key["targeting.corrected.euclidean"]["ours"] == pytest.approx((0.3, 0.1 * np.sqrt(2.0)))
    assert by_key["targeting.corrected.bias.depth"]["paper_key"] == "targeting.bias.depth"
    assert by_key["targeting.rtde_vs_sim"]["ours"] == 0.0 and by_key["targeting.rtde_vs_sim"]["digits"] == 9
    # Neither correction nor second robot: only the paper's figures.
    plain = [c["key"] for c in targeting_comparisons(records_of(robots=("sim",), correction=False))]
    assert plain == keys[:11]


def test_summary_rows_per_robot_and_correction():
    table = summary(records_of())
    assert list(zip(table["robot"], table["targeting"])) == [
        ("sim", "uncorrected (paper)"), ("sim", "bias-corrected"), ("rtde", "uncorrected (paper)"),
        ("rtde", "bias-corrected")]
    assert table.loc[0, "euclidean"] == "3.00 ± 1.41"
    assert table.loc[0, "bias tb"] == "-1.50"


def test_sensitivity_medians_per_condition():
    rows = []
    for n_poses in (4, 8):
        for trial, value in enumerate((1.0, 2.0, 9.0)):
            rows.append({"n_poses": n_poses, "noise_translation_mm": 0.5, "noise_rotation_deg": 0.2, "trial": trial,
                         **{m: value * n_poses for m in SENSITIVITY_METRICS}})
    table = sensitivity_medians(pd.DataFrame(rows))
    assert list(table.columns[:3]) == ["n_poses", "noise_translation_mm", "noise_rotation_deg"]
    assert "trial" not in table
    assert list(table["target_error_mm"]) == [8.0, 16.0]  # the median 2, times n_poses


def test_calibration_sensitivity_table_is_the_seeded_monte_carlo():
    seed = np.random.SeedSequence(7)
    table = calibration_sensitivity_table([4], [[0.5, 0.2]], 3, seed)
    direct = calibration_sensitivity((4,), ((0.5, 0.2),), n_trials=3, rng=np.random.default_rng(seed))
    assert len(table) == 1
    assert table.loc[0, "X_rotation_error_deg"] == direct["X_rotation_error_deg"].median()
    assert "20 trials" in sensitivity_caption(20)


# --- figures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def treated():
    from histostudy.imaging import phantom_mask, phantom_volume, simulate_cbct
    from histostudy.treatment import TreatmentZone, segment_treatment_zone
    from histostudy.treatment.bubble_cloud import post_treatment_phantom

    truth = phantom_volume(spacing_mm=1.0)
    roi = phantom_mask(truth)
    target = np.array([2.0, -3.0, 1.0])
    post = simulate_cbct(post_treatment_phantom(truth, TreatmentZone(target, 20.0).mask(truth), roi), 0)
    return post, segment_treatment_zone(post, roi), target


def test_fig7_figures_of_the_first_robot_only(treated):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    post, seg, target = treated
    records = records_of(n_experiments=3)
    volumes = pd.Series([{"post": post, "segmentation": seg, "target": target}] * len(records), index=records.index)
    made = list(T.fig7_figures(records, volumes, 2))
    assert [name for name, _, _ in made] == ["fig7_experiment_0", "fig7_experiment_1"]
    assert made[1][2].startswith("Fig. 7: experiment 1,")
    assert made[0][1].texts[0].get_text() == "experiment 0: 20 mm zone, error 2.00 mm"
    for _, fig, _ in made:
        plt.close(fig)


def test_fig7_marks_the_target_and_outlines_the_zone(treated):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    post, seg, target = treated
    fig = T.plot_target_slices(post, seg, target)
    axes = fig.axes
    assert len(axes) == 3
    dots = [(line.get_xdata()[0], line.get_ydata()[0]) for ax in axes for line in ax.lines]
    assert np.allclose(dots, [(2.0, -3.0), (2.0, 1.0), (-3.0, 1.0)])  # (x, y), (x, z), (y, z)
    assert all(ax.collections for ax in axes)  # the zone's outline in every cut
    plt.close(fig)
    with pytest.raises(ValueError, match="outside the volume"):
        T.plot_target_slices(post, seg, [500.0, 0.0, 0.0])


def test_scene_figure_feeds_the_3d_scene():
    from histostudy.reporting import targeting_scene

    config = TargetingStudyConfig(background="none")
    rng = np.random.default_rng(5)
    truth = draw_ground_truth(rng, config)
    flanges = T.calibration_poses(rng, config, truth)
    cal = calibrate(flanges, [truth.T_carm_transducer(f) for f in flanges])
    target = truth.T_carm_phantom[:3, 3] + [3.0, -2.0, 4.0]
    seg = SimpleNamespace(sphere_centre_mm=target + 0.5, sphere_radius_mm=9.5)
    records = records_of(robots=("rtde", "sim"))
    records["experiment"] += 3
    volume = {"truth": truth, "calibration": cal, "target": target, "R_des": target_orientation(cal),
              "segmentation": seg}
    volumes = pd.Series([volume] * len(records), index=records.index)
    physical = object()
    figure = T.scene_figure(records, volumes, physical, np.random.SeedSequence(9))
    assert figure.name == "scene_3d_experiment_3"
    assert figure.caption.startswith("Experiment 3 in the C-arm frame")
    scene = figure.scene
    inspect.signature(targeting_scene).bind(None, **scene)  # every key is one of its arguments
    assert scene["model"] is physical and scene["zone_radius_mm"] == 9.5
    assert np.array_equal(scene["zone_centre_mm"], target + 0.5) and np.array_equal(scene["target_mm"], target)
    # The true focal point on the target (exact calibration), from the seeded sampling.
    assert np.linalg.norm(scene["T_carm_transducer"][:3, 3] - target) < 1e-6
    assert scene["rng"].random() == np.random.default_rng(np.random.SeedSequence(9)).random()
