"""Notebook 05's section interface (histostudy.study.targeting): its parameters checked by name, the
set-up made from them, and the parts recorded from the study's records."""


import numpy as np
import pandas as pd
import pytest

from histostudy.study import targeting as T
from histostudy.study.targeting import _section as targeting_notebook
from histostudy.study.targeting._section import (
    RECORDED_PARAMETERS,
    prepare_study,
    stand_ins,
    study_config_from_parameters,
)

#: The parameters cell of notebooks/05_targeting.ipynb as stored (its defaults).
DEFAULTS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu", pose_spacing_mm=0.47,
                render_spacing_mm=0.47, background="phantom", n_experiments=1, zone_diameters_mm=(20.0, 25.0),
                n_calibration_poses=4, pose_mode="fast", degradation="table1", learned_stages=True,
                phantom_voxel_mm=0.5, cbct_voxel_mm=1.0, treatment_spacing_mm=(2.0, 2.0, 3.0),
                bubble_offset_mm=(0.0, 0.0, 0.0), bias_correction=True, robot="both", n_figure_experiments=4,
                sensitivity_poses=(4, 8, 12), sensitivity_noise=((0.25, 0.1), (0.5, 0.2), (1.0, 0.4)),
                sensitivity_trials=5, render_3d=True)


def test_the_parameters_are_the_notebooks_and_the_report_records_the_same_ones(notebook_parameters):
    cell = notebook_parameters("05_targeting")
    params = T.TargetingSectionConfig.from_parameters(cell)
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS  # lists kept as tuples
    assert set(cell) - set(DEFAULTS) == {"profile", "seed", "output_dir"}
    assert list(params.recorded()) == list(RECORDED_PARAMETERS)
    assert params.recorded() == {k: DEFAULTS[k] for k in RECORDED_PARAMETERS}
    assert params.study_config() == study_config_from_parameters({k: cell[k] for k in RECORDED_PARAMETERS})
    with pytest.raises(AttributeError):
        params.robot = "sim"  # frozen


def test_missing_parameters_are_named():
    with pytest.raises(ValueError, match=r"parameters lack \['robot', 'render_3d'\] \(notebook 05's"):
        T.TargetingSectionConfig.from_parameters({k: v for k, v in DEFAULTS.items() if k not in ("robot", "render_3d")})


@pytest.fixture(scope="module")
def setup():
    return T.prepare({**DEFAULTS, "render_spacing_mm": 0.47, "learned_stages": False, "sensitivity_poses": [3],
                      "sensitivity_noise": [[0.5, 0.2]], "sensitivity_trials": 2}, 20230119)


def test_prepare_is_prepare_study_on_the_checked_parameters(setup):
    assert isinstance(setup.params, T.TargetingSectionConfig) and setup.params.sensitivity_poses == (3,)
    plain = prepare_study(setup.params.recorded(), 20230119)
    assert setup.config == plain.config and setup.seeds.study == plain.seeds.study
    assert np.array_equal(setup.physical.focal_point_mm, plain.physical.focal_point_mm)


def test_the_parts_of_a_run(setup, monkeypatch, recording_timer):
    def fake_study(config, **kw):
        return pd.DataFrame({"robot": [kw["robot"]], "_volumes": [{"post": "volume"}]})

    monkeypatch.setattr(targeting_notebook, "run_targeting_study", fake_study)
    monkeypatch.setattr(targeting_notebook, "error_table", lambda records: records.assign(shown=True))
    timer, timed = recording_timer()

    run = T.experiments_section(setup, timer=timer)
    assert list(run.records["robot"]) == ["both"] and run.volumes.iloc[0] == {"post": "volume"}
    assert list(run.part.tables) == ["targeting_errors"] and run.part.table("targeting_errors")["shown"].all()
    sensitivity = T.sensitivity_section(setup, timer=timer)
    assert timed == ["targeting study", "calibration sensitivity"]
    assert sensitivity.part.values["calibration_sensitivity_medians"] == sensitivity.table.to_dict("records")
    closing = T.closing_part(setup, run.records)
    assert closing.stand_ins == tuple(stand_ins("both", False, (0.0, 0.0, 0.0)))
    assert closing.texts[0].startswith("1 experiment(s).")
