"""Notebook 05's set-up and prose (histostudy.study.targeting._notebook) and the per-zone and
calibration error rows of an experiment (histostudy.study.targeting._experiment), on known values."""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.study.targeting import _section as targeting_notebook
from histostudy.study.targeting._section import (
    RECORDED_PARAMETERS,
    TargetingSetup,
    closing_text,
    notebook_seeds,
    prepare_study,
    run_prepared_study,
    stand_ins,
    study_config_from_parameters,
)
from histostudy.study.targeting.experiment import calibration_errors, zone_errors
from histostudy.study.targeting.setup import TargetingStudyConfig
from histostudy.transducer import TransducerModel, TransducerSpec

#: The smoke profile's notebook-05 parameters (histostudy/reporting/profiles/smoke.toml).
SMOKE = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, pose_spacing_mm=0.47, render_spacing_mm=0.47,
             splat_device="cpu",
             background="phantom", n_experiments=1, zone_diameters_mm=[20.0, 25.0], n_calibration_poses=4,
             pose_mode="fast", degradation="table1", learned_stages=False, phantom_voxel_mm=0.5, cbct_voxel_mm=1.0,
             treatment_spacing_mm=[2.0, 2.0, 3.0], bubble_offset_mm=[0.0, 0.0, 0.0], bias_correction=True,
             robot="both")


def test_notebook_seeds_are_the_children_the_notebook_always_used():
    """The four seeds are SeedSequence(seed).spawn(2) (physical, study), .spawn(3)[2] and .spawn(4)[3]:
    the draws the notebook made before its set-up moved into the package."""
    seeds = notebook_seeds(20230119)
    physical, study = np.random.SeedSequence(20230119).spawn(2)
    assert np.array_equal(seeds.physical.generate_state(8), physical.generate_state(8))
    assert seeds.study == int(study.generate_state(1)[0])
    assert np.array_equal(seeds.sensitivity.generate_state(8),
                          np.random.SeedSequence(20230119).spawn(3)[2].generate_state(8))
    assert np.array_equal(seeds.scene.generate_state(8), np.random.SeedSequence(20230119).spawn(4)[3].generate_state(8))
    assert notebook_seeds(1).study != seeds.study


def test_config_from_parameters_takes_the_config_fields_only():
    config = study_config_from_parameters(SMOKE)
    assert config == TargetingStudyConfig(
        n_experiments=1, zone_diameters_mm=(20.0, 25.0), n_calibration_poses=4, background="phantom",
        photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu", degradation="table1",
        pose_mode="fast",
        phantom_voxel_mm=0.5, cbct_voxel_mm=1.0, treatment_spacing_mm=(2.0, 2.0, 3.0),
        bubble_offset_mm=(0.0, 0.0, 0.0), bias_correction=True)
    assert config.treatment_spacing_mm == (2.0, 2.0, 3.0)  # lists made tuples (the config is hashable)
    hash(config)
    with pytest.raises(ValueError, match="n_calibration_poses"):
        study_config_from_parameters({**SMOKE, "n_calibration_poses": 2})


def test_recorded_parameters_are_parameters_of_notebook_05():
    import ast
    import json
    from pathlib import Path

    notebook = Path(__file__).resolve().parents[3] / "notebooks" / "05_targeting.ipynb"
    cells = json.loads(notebook.read_text())["cells"]
    (source,) = ["".join(c["source"]) for c in cells if "parameters" in c.get("metadata", {}).get("tags", [])]
    names = {t.id for node in ast.parse(source).body if isinstance(node, ast.Assign) for t in node.targets}
    assert set(RECORDED_PARAMETERS) <= names
    assert len(set(RECORDED_PARAMETERS)) == len(RECORDED_PARAMETERS) == len(SMOKE)


def test_prepare_study_builds_the_seeded_set_up(recording_timer):
    timer, timed = recording_timer()

    setup = prepare_study(SMOKE, 20230119, timer=timer)
    assert timed == ["build models"]
    assert setup.config == study_config_from_parameters(SMOKE)
    assert setup.seeds.study == notebook_seeds(20230119).study
    expected = TransducerModel.build_physical(TransducerSpec(), spacing_mm=0.47,
                                              rng=np.random.default_rng(notebook_seeds(20230119).physical))
    assert np.array_equal(setup.physical.focal_point_mm, expected.focal_point_mm)
    assert setup.pose_model.spacing_mm == 0.47 and len(setup.views) == 2
    assert not setup.stages.learned  # learned_stages=False: the oracles


def test_run_prepared_study_passes_the_set_up_and_splits_the_volumes(monkeypatch):
    calls = {}

    def fake_study(config, **kw):
        calls.update(config=config, **kw)
        return pd.DataFrame({"robot": ["sim"], "err_euclidean": [1.5], "_volumes": [{"post": "volume"}]})

    monkeypatch.setattr(targeting_notebook, "run_targeting_study", fake_study)
    stages = SimpleNamespace(segmenter="U-Net", orientation="VGG19")
    setup = TargetingSetup(TargetingStudyConfig(), "pose", "render", "physical", ("A", "B"), stages,
                             notebook_seeds(3))
    records, volumes = run_prepared_study(setup, "rtde")
    assert "_volumes" not in records and list(records["err_euclidean"]) == [1.5]
    assert volumes.iloc[0] == {"post": "volume"}
    assert calls["seed"] == setup.seeds.study and calls["robot"] == "rtde" and calls["keep_volumes"] is True
    assert (calls["pose_model"], calls["render_model"], calls["physical"]) == ("pose", "render", "physical")
    assert (calls["segmenter"], calls["orientation"]) == ("U-Net", "VGG19")


def test_stand_ins_name_the_robot_stages_and_offset():
    both = dict(stand_ins("both", True, [1.0, 0.0, -1.5]))
    assert "ur_rtde" in both["the UR5e"]
    assert "shipped" in both["U-Net segmentation and VGG19 orientation of the calibration frames"]
    assert "[1.0, 0.0, -1.5] mm" in both["the bubble cloud"]
    sim = dict(stand_ins("sim", False, [0.0, 0.0, 0.0]))
    assert sim["the UR5e"] == "SimulatedUR5e in process"
    assert "Table I" in sim["U-Net segmentation and VGG19 orientation of the calibration frames"]
    assert len(stand_ins("rtde", True, [0, 0, 0])) == 6


def test_closing_text_states_the_offsets():
    setup = SimpleNamespace(physical=SimpleNamespace(focal_point_mm=np.array([3.0, 4.0, 0.0])),
                            config=TargetingStudyConfig(bias_test_diameter_mm=25.0))
    text = closing_text(2, setup, [0.5, 0.0, 0.0])
    assert text.startswith("2 experiment(s).")
    assert "lies 5.00 mm from the digital model's" in text
    assert "[0.5, 0.0, 0.0] mm" in text and "25 mm test zone" in text


# --- the error rows of one experiment ---------------------------------------------------------


def test_zone_errors_along_the_commanded_axes():
    seg = SimpleNamespace(centroid_mm=np.array([11.0, 22.0, 33.0]), sphere_radius_mm=9.0)
    # Transducer axes = C-arm axes: LR = x, TB = y, depth (propagation) = -z.
    row = zone_errors("corr_", seg, np.array([10.0, 20.0, 30.0]), np.eye(3), 10.0)
    assert row == pytest.approx({"corr_err_depth": -3.0, "corr_err_tb": 2.0, "corr_err_lr": 1.0,
                                 "corr_err_euclidean": np.sqrt(14.0), "corr_radius_mm": 9.0,
                                 "corr_radius_err_mm": -1.0, "corr_centroid_x": 11.0, "corr_centroid_y": 22.0,
                                 "corr_centroid_z": 33.0})
    # Turned a quarter about the propagation axis: LR is now along y.
    turned = zone_errors("", seg, np.array([10.0, 20.0, 30.0]), rotation_about_axis([0, 0, 1], np.pi / 2), 10.0)
    assert turned["err_lr"] == pytest.approx(2.0) and turned["err_tb"] == pytest.approx(-1.0)


def test_calibration_errors_against_a_known_truth():
    X_true = make_transform(np.eye(3), [0.0, 0.0, 250.0])
    Y_true = make_transform(np.eye(3), [-600.0, 100.0, 0.0])
    truth = SimpleNamespace(T_flange_transducer=X_true, T_carm_base=Y_true)
    cal = SimpleNamespace(T_flange_transducer=make_transform(rotation_about_axis([1, 0, 0], np.radians(0.5)),
                                                             [0.0, 3.0, 254.0]),
                          T_carm_base=make_transform(rotation_about_axis([0, 0, 1], np.radians(-0.2)),
                                                     [-600.0, 100.0, 1.5]),
                          rms_focal_residual_mm=0.4, max_rotation_residual_deg=0.3)
    rows = pd.DataFrame({"pose_error_mm": [0.5, 1.5]})
    errors = calibration_errors(cal, rows, truth)
    assert errors == pytest.approx({"cal_rms_focal_residual_mm": 0.4, "cal_max_rotation_residual_deg": 0.3,
                                    "cal_pose_error_mm": 1.0, "cal_X_rotation_deg": 0.5, "cal_X_translation_mm": 5.0,
                                    "cal_Y_rotation_deg": 0.2, "cal_Y_translation_mm": 1.5})
