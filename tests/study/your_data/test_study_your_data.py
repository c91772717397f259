"""histostudy.study.your_data (notebook 06): its inputs found or refused by name, its tables and
figures on known values. The whole path on the generated dataset runs in the smoke study
(tests/reporting/test_notebooks.py) and through the CLI (tests/cli/test_cli_lab.py)."""

import json

import matplotlib
import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import Volume
from histostudy.lab import TargetingPlan
from histostudy.study import your_data as study
from histostudy.study.your_data import _inputs

matplotlib.use("Agg")


def _layout(folder, *, cbct=True, manifest=None):
    (folder / "calibration" / "station_0").mkdir(parents=True)
    (folder / "cine").mkdir()
    (folder / "cine" / "A.dcm").write_bytes(b"")
    if cbct:
        (folder / "cbct.nii.gz").write_bytes(b"")
    if manifest is not None:
        (folder / "dataset.json").write_text(json.dumps(manifest))
    return folder


def test_a_lab_folder_is_read_and_its_gaps_named(tmp_path):
    folder = _layout(tmp_path / "lab", manifest={"suggested_target_mm": [1.0, 2.0, 3.0]})
    inputs = _inputs.lab_inputs(folder, output_dir=tmp_path / "out", seed=0)
    assert inputs.stations == (folder / "calibration" / "station_0",) and inputs.truth is None
    np.testing.assert_array_equal(inputs.target_mm, [1.0, 2.0, 3.0])
    assert inputs.views is None and inputs.transducer_meshes is None and inputs.generated
    # A lab's own folder: no manifest, so the target must be given.
    bare = _layout(tmp_path / "bare", cbct=True)
    with pytest.raises(ValueError, match="target_mm must be given"):
        _inputs.lab_inputs(bare, output_dir=tmp_path / "out", seed=0)
    assert _inputs.lab_inputs(bare, output_dir=tmp_path, seed=0, target_mm=[0, 0, 0]).generated is False
    with pytest.raises(FileNotFoundError, match=r"lacks \['cbct'\]"):
        _inputs.lab_inputs(_layout(tmp_path / "nocbct", cbct=False), output_dir=tmp_path, seed=0, target_mm=[0, 0, 0])
    with pytest.raises(FileNotFoundError, match="no such folder"):
        _inputs.lab_inputs(tmp_path / "missing", output_dir=tmp_path, seed=0)


def test_the_focal_errors_pool_the_accepted_poses_only():
    stations = pd.DataFrame({"accepted": [True, False, True], "focal_error_mm": [0.2, 9.0, 0.4]})
    cine = pd.DataFrame({"accepted": [True], "focal_error_mm": [0.6]})
    mean, sd = study.accepted_focal_errors(stations, cine)
    assert mean == pytest.approx(0.4) and sd == pytest.approx(0.2)
    assert study.accepted_focal_errors(stations.drop(columns="focal_error_mm"), cine.drop(columns="focal_error_mm")) \
        is None


def test_the_plan_table_and_the_cbct_figure_show_the_plan():
    plan = TargetingPlan(target_mm=np.array([1.0, 2.0, 3.0]), R_carm_transducer=np.eye(3), T_flange_tcp=np.eye(4),
                         T_base_tcp=np.eye(4), T_base_flange=np.eye(4), start_joints_rad=np.zeros(6),
                         joints_rad=np.full(6, np.radians(2.0)), joint_travel_rad=float(np.radians(2.0)))
    table = study.plan_table(plan)
    assert table.loc[table["quantity"] == "largest joint move (deg)", "value"].item() == pytest.approx(2.0)
    volume = Volume.from_bounds([-20, -20, -20], [20, 20, 20], 1.0)
    fig = _inputs.plot_cbct_target(volume, [1.0, 2.0, 3.0])
    assert len(fig.axes) == 3
    with pytest.raises(ValueError, match="outside the volume"):
        _inputs.plot_cbct_target(volume, [100.0, 0.0, 0.0])
