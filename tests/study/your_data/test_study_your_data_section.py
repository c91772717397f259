"""Notebook 06's section interface (histostudy.study.your_data): its parameters checked by name, the
parts it records, and the one call that drives the robot — planned and checked from the robot's
joints, moved only when not a dry run (a SimulatedUR5e counts its moves)."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import Volume
from histostudy.lab import TargetingPlan, calibrate_from_poses
from histostudy.robot import SimulatedUR5e, UnreachablePoseError
from histostudy.study import your_data as study
from histostudy.study.section import SectionPart
from histostudy.study.targeting import calibration_poses
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth, start_joints
from histostudy.study.your_data import _section as section_module

#: The parameters cell of notebooks/06_your_data.ipynb as stored (its defaults).
DEFAULTS = dict(data_dir=None, target_mm=None, n_cine_frames=4, max_tracked_frames=4, stream_cine=True,
                moving_cine_s=2.0, moving_cine_fps=7.5, moving_cine_speed_mm_s=10.0, max_queued_pairs=2,
                photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, pose_spacing_mm=0.47, robot_host=None,
                splat_device="cpu",
                dry_run=True, speed_mm_s=50.0)


def _notebook_parameters() -> dict:
    notebook = Path(__file__).resolve().parents[3] / "notebooks" / "06_your_data.ipynb"
    (cell,) = [c for c in json.loads(notebook.read_text())["cells"]
               if "parameters" in c.get("metadata", {}).get("tags", [])]
    namespace: dict = {}
    exec("".join(cell["source"]), namespace)
    return {k: v for k, v in namespace.items() if not k.startswith("__")}


def test_the_parameters_are_the_notebooks_and_the_report_records_the_same_ones():
    cell = _notebook_parameters()
    params = study.YourDataConfig.from_parameters(cell)
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS
    assert set(cell) - set(DEFAULTS) == {"profile", "seed", "output_dir"}
    assert list(params.recorded()) == list(study.YourDataConfig.RECORDED)
    assert params.recorded() == {k: DEFAULTS[k] for k in study.YourDataConfig.RECORDED}
    assert params.render() == {"photons_per_pixel": 50000.0, "n_splats": 16, "splat_sigma_mm": 0.5,
                               "splat_device": "cpu"}
    with pytest.raises(AttributeError):
        params.dry_run = False  # frozen
    given = study.YourDataConfig(**{**DEFAULTS, "target_mm": [1, 2, 3], "moving_cine_s": 0})
    assert given.target_mm == (1.0, 2.0, 3.0) and given.moving_cine_s == 0.0


def test_missing_parameters_are_named():
    with pytest.raises(ValueError, match=r"parameters lack \['dry_run', 'speed_mm_s'\]"):
        study.YourDataConfig.from_parameters({k: v for k, v in DEFAULTS.items()
                                                  if k not in ("dry_run", "speed_mm_s")})


class _Writer:
    """What record() calls on a SectionWriter, in order."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, method):
        return lambda *args, **kwargs: self.calls.append((method, args[0] if args else kwargs["key"]))


def test_record_writes_tables_figures_values_and_comparisons_in_order():
    part = SectionPart(tables={"a": (pd.DataFrame(), ""), "b": (pd.DataFrame(), "")},
                             figures={"f": (object(), "")}, values={"v": 1},
                             comparisons=(dict(key="k", label="", ours=1.0),))
    writer = _Writer()
    study.record(writer, part, SectionPart(values={"w": 2}))
    assert writer.calls == [("table", "a"), ("table", "b"), ("figure", "f"), ("value", "v"), ("compare", "k"),
                            ("value", "w")]
    assert study.focal_error_part(None).comparisons == ()
    assert study.focal_error_part((0.5, 0.1)).comparisons[0]["paper_key"] == "table2.center_mae.overall"
    with pytest.raises(TypeError, match="SectionPart"):
        study.record(writer, {"tables": {}})


# --- the robot ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lab():
    """An exact synthetic lab: the true chain, a calibration on it, a target inside a CBCT."""
    rng = np.random.default_rng(21)
    truth = draw_ground_truth(rng, TargetingStudyConfig(n_experiments=1, background="none"))
    F = calibration_poses(rng, TargetingStudyConfig(n_experiments=1, background="none"), truth)
    calibration = calibrate_from_poses([{"T_carm_transducer": truth.T_carm_transducer(f), "accepted": True}
                                        for f in F], F)
    target = truth.T_carm_phantom[:3, 3] + np.array([4.0, -3.0, 6.0])
    inputs = study.LabInputs(views=None, stations=(), flange_poses=Path("flange_poses.json"), cine=(),
                             cbct=Path("cbct.nii.gz"), transducer_meshes=None, target_mm=target, truth=None,
                             generated=False)
    return truth, calibration, inputs, Volume.from_bounds(target - 40, target + 40, 2.0)


def test_a_dry_run_plans_from_the_robots_joints_and_moves_nothing(lab):
    truth, calibration, inputs, volume = lab
    robot = SimulatedUR5e(0, repeatability_mm=0.0, initial_joints_rad=start_joints(truth))
    plan, executed = study.drive_robot(calibration, inputs, volume, robot=robot)  # dry_run=True by default
    assert isinstance(plan, TargetingPlan) and executed is None
    np.testing.assert_allclose(plan.start_joints_rad, start_joints(truth))
    assert robot.state().moves_completed == 0 and robot.state().connected  # a robot passed in stays open
    # No robot: the plan starts from home, and dry_run=False moves nothing either.
    plan, executed = study.drive_robot(calibration, inputs, volume, robot=None, dry_run=False)
    assert executed is None and plan.workspace_ok


def test_not_a_dry_run_makes_the_one_checked_move_onto_the_target(lab):
    truth, calibration, inputs, volume = lab
    robot = SimulatedUR5e(0, repeatability_mm=0.0, initial_joints_rad=start_joints(truth))
    plan, executed = study.drive_robot(calibration, inputs, volume, robot=robot, dry_run=False, speed_mm_s=100.0)
    assert robot.state().moves_completed == 1 and executed["position_error_mm"] < 1e-6
    T_true = truth.T_carm_transducer(robot.flange_pose())  # the true chain puts the focal point on the target
    assert np.linalg.norm(T_true[:3, 3] - inputs.target_mm) < 1e-6


class _JoggedUR5e(SimulatedUR5e):
    """A robot jogged (by hand, by another program) after its joints were read for the plan."""

    def joints(self):
        q = super().joints()
        self.reads = getattr(self, "reads", 0) + 1
        return q if self.reads == 1 else q + 0.01


def test_an_unchecked_pose_is_never_moved_to(lab):
    truth, calibration, inputs, volume = lab
    # The robot is no longer where the plan was checked from: refused before any move.
    jogged = _JoggedUR5e(0, repeatability_mm=0.0, initial_joints_rad=start_joints(truth))
    with pytest.raises(ValueError, match="plan again from where it is"):
        study.drive_robot(calibration, inputs, volume, robot=jogged, dry_run=False)
    assert jogged.state().moves_completed == 0
    # A target outside the CBCT, or out of reach: no plan, no move.
    robot = SimulatedUR5e(0, repeatability_mm=0.0, initial_joints_rad=start_joints(truth))
    far = study.LabInputs(**{**vars(inputs), "target_mm": inputs.target_mm + 100.0})
    with pytest.raises(ValueError, match="outside the CBCT volume"):
        study.drive_robot(calibration, far, volume, robot=robot, dry_run=False)
    unreachable = study.LabInputs(**{**vars(inputs), "target_mm": inputs.target_mm + np.array([1500.0, 0, 0])})
    with pytest.raises(UnreachablePoseError):
        study.drive_robot(calibration, unreachable, Volume.from_bounds(unreachable.target_mm - 10,
                                                                       unreachable.target_mm + 10, 2.0),
                          robot=robot, dry_run=False)
    assert robot.state().moves_completed == 0


def test_the_robot_arguments_are_checked(lab):
    _, calibration, inputs, volume = lab
    with pytest.raises(ValueError, match="dry_run must be True or False, got 'no'"):
        study.drive_robot(calibration, inputs, volume, dry_run="no")
    with pytest.raises(ValueError, match="speed_mm_s must be a finite number > 0 mm/s, got 0"):
        study.drive_robot(calibration, inputs, volume, speed_mm_s=0)
    with pytest.raises(TypeError, match="robot must be None, a UR controller's host"):
        study.drive_robot(calibration, inputs, volume, robot=object())


def test_prepare_reads_the_lab_folder_and_times_the_set_up(tmp_path, monkeypatch, recording_timer):
    timer, timed = recording_timer()

    monkeypatch.setattr(section_module, "lab_inputs", lambda data_dir, **kw: ("inputs", data_dir, kw))
    monkeypatch.setattr(section_module, "transducer_model", lambda inputs, spacing: ("model", spacing))
    setup = study.prepare({**DEFAULTS, "data_dir": "lab", "pose_spacing_mm": 0.5}, 7, tmp_path, timer=timer)
    assert timed == ["inputs"] and setup.seed == 7 and setup.output_dir == tmp_path
    assert setup.inputs == ("inputs", "lab", dict(output_dir=tmp_path, seed=7, target_mm=None, n_cine_frames=4,
                                                  render=setup.params.render()))
    assert setup.model == ("model", 0.5)
    with pytest.raises(ValueError, match="n_cine_frames must be an integer >= 1, got 0"):
        study.prepare({**DEFAULTS, "n_cine_frames": 0}, 7, tmp_path)


def test_notebook_06_is_thin_and_uses_no_private_name():
    """Issue 35: at most 60 lines of code (non-blank, non-comment, in code cells), no private name of
    histostudy reached from the notebook (``_module`` or ``obj._name``)."""
    import ast

    notebook = Path(__file__).resolve().parents[3] / "notebooks" / "06_your_data.ipynb"
    cells = [c for c in json.loads(notebook.read_text())["cells"] if c["cell_type"] == "code"]
    source = "\n".join("".join(c["source"]) for c in cells)
    lines = [line for line in source.splitlines() if line.strip() and not line.strip().startswith("#")]
    assert len(lines) <= 60
    private = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            private += [p for p in (node.module or "").split(".") + [a.name for a in node.names] if p.startswith("_")]
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_"):
            private.append(node.attr)
    assert private == []
