"""The lab's subcommands end to end on the generated lab-like dataset (histostudy.study.your_data.lab_dataset):
DICOM XA stations -> ``calibrate`` -> ``target`` as a dry run, and executed on the simulated UR
controller through ur_rtde; every result measured against the dataset's synthetic truth."""

import json

import numpy as np
import pydicom
import pytest

from histostudy.cli import main
from histostudy.robot import forward_kinematics
from histostudy.robot.controller._process import ControllerProcess


@pytest.fixture(scope="module")
def calibration_file(lab, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "calibration.json"
    stations = [str(p.parent) for p, _ in lab.calibration_frames]
    assert main(["calibrate", *stations, "--flange-poses", str(lab.flange_poses), "--output", str(out)]) == 0
    return out


@pytest.mark.slow
def test_calibrate_on_the_stations_recovers_the_true_chain_at_the_target(calibration_file, lab, truth):
    cal = json.loads(calibration_file.read_text())
    assert cal["schema"] == "histostudy.calibration/1" and len(cal["stations"]) == 4
    # Where the calibrated and the true chain put a point at the target: the calibration's error there.
    D = truth["T_carm_base"] @ np.linalg.inv(np.asarray(cal["T_carm_base"]))
    error = np.linalg.norm(D[:3, :3] @ lab.target_mm + D[:3, 3] - lab.target_mm)
    assert error < 2.0, f"T_carm_base off by {error:.2f} mm at the target"
    # the study its stations were acquired in (the dataset's one procedure), for `target --pose`
    study = pydicom.dcmread(lab.calibration_frames[0][0], stop_before_pixels=True).StudyInstanceUID
    assert cal["study_instance_uids"] == [study]


@pytest.mark.slow
def test_target_plans_a_dry_run_and_refuses_to_move_without_a_robot(calibration_file, lab, tmp_path, capsys):
    out = tmp_path / "target.json"
    x, y, z = lab.target_mm
    code = main(["target", "--calibration", str(calibration_file), f"--target={x},{y},{z}", "--cbct",
                 str(lab.cbct), "--output", str(out)])
    captured = capsys.readouterr()
    assert code == 0 and "dry run: nothing moved" in captured.err
    summary = json.loads(captured.out)  # stdout: the summary, one JSON line
    assert summary["command"] == "target" and summary["dry_run"] is True and summary["moved"] is False
    np.testing.assert_allclose(summary["target_mm"], lab.target_mm)
    plan = json.loads(out.read_text())
    assert plan["dry_run"] is True and plan["executed"] is None
    np.testing.assert_allclose(plan["plan"]["target_mm"], lab.target_mm)
    assert main(["target", "--calibration", str(calibration_file), "--target", "0,0,0", "--execute",
                 "--output", str(tmp_path / "no.json")]) == 2
    assert "--execute moves a robot" in capsys.readouterr().err
    # A voxel index outside the CBCT is refused, naming the volume's extent; nothing is written.
    assert main(["target", "--calibration", str(calibration_file), "--target-voxel", "9999,0,0", "--cbct",
                 str(lab.cbct), "--output", str(tmp_path / "no.json")]) == 2
    assert "outside the CBCT volume" in capsys.readouterr().err
    assert not (tmp_path / "no.json").exists()


@pytest.mark.slow
def test_target_executed_on_the_simulated_controller_puts_the_true_focal_point_on_the_target(
        calibration_file, lab, truth, tmp_path):
    q0 = truth["cine_start_joints_rad"]
    out = tmp_path / "moved.json"
    x, y, z = lab.target_mm
    with ControllerProcess("127.0.0.61", "--seed", "0", "--repeatability-mm", "0", "--initial-joints",
                           *map(repr, map(float, q0))) as controller:
        code = main(["target", "--calibration", str(calibration_file), f"--target={x},{y},{z}", "--robot",
                     controller.host, "--execute", "--speed-mm-s", "200", "--output", str(out)])
    assert code == 0
    moved = json.loads(out.read_text())
    assert moved["dry_run"] is False and moved["executed"]["position_error_mm"] < 0.1
    # Through the TRUE chain: the transducer's focal point where the robot actually went.
    flange = forward_kinematics(np.asarray(moved["executed"]["joints_rad"]))
    focal = (truth["T_carm_base"] @ flange @ truth["T_flange_transducer"])[:3, 3]
    assert np.linalg.norm(focal - lab.target_mm) < 2.0


def test_bad_input_to_the_lab_commands_is_named(tmp_path, capsys):
    (tmp_path / "flange.json").write_text(json.dumps({"T_base_flange": []}))
    assert main(["calibrate", str(tmp_path / "missing.json"), "--flange-poses", str(tmp_path / "flange.json")]) == 2
    assert "missing.json" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(["target", "--calibration", "c.json", "--target", "1,2"])
    assert done.value.code == 2 and "expected three finite numbers" in capsys.readouterr().err
    for command in ("pose", "calibrate", "target", "listen", "reproduce", "report", "train", "profiles"):
        with pytest.raises(SystemExit) as done:
            main([command, "--version"])
        assert done.value.code == 0 and capsys.readouterr().out.startswith("histostudy ")


@pytest.mark.slow
def test_pose_with_the_transducer_from_its_cad_meshes(lab, truth, tmp_path, capsys):
    a, b = lab.calibration_frames[1]
    out = tmp_path / "pose.json"
    code = main(["pose", str(a), str(b), "--transducer", str(lab.folder / "transducer"), "--output", str(out)])
    record = json.loads(out.read_text())
    assert code == (0 if record["accepted"] else 1)
    error = np.linalg.norm(np.asarray(record["T_carm_transducer"])[:3, 3]
                           - truth["station_T_carm_transducer"][1][:3, 3])
    assert error < 2.0
    assert record["study_instance_uid"] == pydicom.dcmread(a, stop_before_pixels=True).StudyInstanceUID
    assert main(["pose", str(a), str(b), "--transducer", str(tmp_path / "none"), "--output", str(tmp_path / "x")]) == 2
    assert "no such folder of meshes" in capsys.readouterr().err
