"""``histostudy target``'s coordinates against an independent reference (nibabel's affine of the
generated dataset's cbct.nii.gz, RAS): the voxel, the RAS point and the LPS point of one target give
the same plan, and the files say which frame they are in; the pose's half-turn reading is named.
The calibration is the dataset's true chain, written directly: no pose estimate is needed."""

import json

import nibabel as nib
import numpy as np
import pytest
from nibabel.affines import apply_affine

from histostudy.calibration import HandEyeCalibration
from histostudy.cli import main
from histostudy.core import WORLD_FRAME
from histostudy.lab import plan_targeting
from histostudy.lab.workflow import READINGS
from histostudy.transducer import HALF_TURN

VOXEL = (36, 37, 31)


@pytest.fixture(scope="module")
def calibration_file(truth, tmp_path_factory):
    calibration = HandEyeCalibration(T_flange_transducer=truth["T_flange_transducer"], T_carm_base=truth["T_carm_base"],
                                     rotation_residuals_deg=[0.0] * 4, translation_residuals_mm=[0.0] * 4,
                                     focal_residuals_mm=[0.0] * 4)
    return calibration.save(tmp_path_factory.mktemp("cal") / "calibration.json")


def _target(capsys, calibration_file, out, *args):
    code = main(["target", "--calibration", str(calibration_file), *args, "--output", str(out)])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    return code, summary, json.loads(out.read_text()) if out.exists() else None


@pytest.mark.slow
def test_the_voxel_is_nibabels_point_with_x_and_y_negated(lab, calibration_file, tmp_path, capsys):
    ras = apply_affine(nib.load(lab.cbct).affine, VOXEL)  # nibabel: RAS mm
    code, summary, written = _target(capsys, calibration_file, tmp_path / "v.json",
                                     "--target-voxel", ",".join(map(str, VOXEL)), "--cbct", str(lab.cbct))
    assert code == 0
    np.testing.assert_allclose(written["plan"]["target_mm"], ras * [-1, -1, 1], atol=1e-9)
    np.testing.assert_allclose(written["plan"]["target_ras_mm"], ras, atol=1e-9)
    np.testing.assert_allclose(summary["target_mm"], ras * [-1, -1, 1], atol=1e-9)
    np.testing.assert_allclose(summary["target_ras_mm"], ras, atol=1e-9)
    assert summary["target_frame_given"] == written["target_frame_given"] == "voxel"
    assert written["target_given"] == list(VOXEL)
    assert written["frame"] == written["plan"]["frame"] == summary["frame"] == WORLD_FRAME
    assert written["plan"]["units"] == {"length": "mm", "angle": "rad"}


@pytest.mark.slow
def test_a_ras_point_plans_as_its_voxel_and_its_lps_point(lab, calibration_file, tmp_path, capsys):
    ras = apply_affine(nib.load(lab.cbct).affine, VOXEL)
    lps = ras * [-1, -1, 1]
    runs = {
        "voxel": ["--target-voxel", ",".join(map(str, VOXEL))],
        "ras": [f"--target={','.join(map(repr, ras.tolist()))}", "--target-frame", "ras"],
        "lps": [f"--target={','.join(map(repr, lps.tolist()))}"],
    }
    plans = {}
    for given, args in runs.items():
        code, summary, written = _target(capsys, calibration_file, tmp_path / f"{given}.json", *args,
                                         "--cbct", str(lab.cbct))
        assert code == 0 and summary["target_frame_given"] == given
        plans[given] = written["plan"]
        # the pair in the file: RAS is LPS with x and y negated
        np.testing.assert_allclose(written["plan"]["target_ras_mm"], np.multiply(written["plan"]["target_mm"],
                                                                                 [-1, -1, 1]))
    for given in ("ras", "lps"):
        np.testing.assert_allclose(plans[given]["target_mm"], plans["voxel"]["target_mm"], atol=1e-9)
        np.testing.assert_allclose(plans[given]["joints_rad"], plans["voxel"]["joints_rad"], atol=1e-9)
    # the same numbers read as LPS are the mirrored point: not the voxel's target
    code, _, mirrored = _target(capsys, calibration_file, tmp_path / "m.json", runs["ras"][0])
    assert code == 0 and np.linalg.norm(np.subtract(mirrored["plan"]["target_mm"], lps)) > 1.0


def test_an_unknown_target_frame_is_refused_naming_the_choices(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main(["target", "--calibration", "c.json", "--target", "1,2,3", "--target-frame", "xyz"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and "--target-frame" in err and "'lps', 'ras'" in err and "'xyz'" in err


@pytest.mark.slow
def test_a_target_frame_for_a_voxel_is_refused(lab, calibration_file, tmp_path, capsys):
    code = main(["target", "--calibration", str(calibration_file), "--target-voxel", "1,2,3", "--target-frame", "ras",
                 "--cbct", str(lab.cbct), "--output", str(tmp_path / "no.json")])
    assert code == 2 and "--target-frame ras gives the axes of --target" in capsys.readouterr().err
    assert not (tmp_path / "no.json").exists()


@pytest.mark.slow
def test_the_plan_says_which_reading_of_the_pose_it_used(lab, truth, calibration_file, tmp_path, capsys):
    T = np.asarray(truth["cine_T_carm_transducer"][0])
    turned = T.copy()
    turned[:3, :3] = T[:3, :3] @ HALF_TURN
    x, y, z = lab.target_mm
    chosen = {}
    for name, pose in (("recorded", T), ("turned", turned)):
        record = tmp_path / f"{name}.json"
        record.write_text(json.dumps({"T_carm_transducer": pose.tolist(), "accepted": True,
                                      "half_turn": {"symmetric": True}}))
        code, summary, written = _target(capsys, calibration_file, tmp_path / f"t_{name}.json",
                                         f"--target={x},{y},{z}", "--pose", str(record))
        assert code == 0 and summary["orientation_reading"] == written["plan"]["orientation_reading"]
        chosen[name] = written["plan"]
        # checked against planning each reading here, from the same start (no robot: home)
        calibration = HandEyeCalibration.load(calibration_file)
        travel = {r: plan_targeting(calibration, lab.target_mm, orientation=R).joint_travel_rad
                  for r, R in zip(READINGS, (pose[:3, :3], pose[:3, :3] @ HALF_TURN))}
        assert summary["orientation_reading"] == min(travel, key=travel.get)
        assert written["plan"]["joint_travel_rad"] == pytest.approx(min(travel.values()))
    assert chosen["recorded"]["orientation_reading"] != chosen["turned"]["orientation_reading"]
    np.testing.assert_allclose(chosen["recorded"]["R_carm_transducer"], chosen["turned"]["R_carm_transducer"],
                               atol=1e-12)
    # a record of a transducer that is not its own half turn keeps its orientation
    record = tmp_path / "asymmetric.json"
    record.write_text(json.dumps({"T_carm_transducer": turned.tolist(), "accepted": True,
                                  "half_turn": {"symmetric": False}}))
    code, summary, written = _target(capsys, calibration_file, tmp_path / "t_a.json", f"--target={x},{y},{z}",
                                     "--pose", str(record))
    assert code == 0 and summary["orientation_reading"] == "as recorded"
    np.testing.assert_allclose(written["plan"]["R_carm_transducer"], turned[:3, :3], atol=1e-9)


@pytest.mark.slow
def test_calibrate_writes_its_frame(lab, truth, tmp_path, capsys):
    stations = []
    for k, T in enumerate(truth["station_T_carm_transducer"]):
        stations.append(tmp_path / f"station_{k}.json")
        stations[-1].write_text(json.dumps({"T_carm_transducer": np.asarray(T).tolist(), "accepted": True,
                                            "focal_point_mm": np.asarray(T)[:3, 3].tolist()}))
    out = tmp_path / "calibration.json"
    assert main(["calibrate", *map(str, stations), "--flange-poses", str(lab.flange_poses), "--output", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["frame"] == WORLD_FRAME and written["units"]["length"] == "mm"
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["frame"] == WORLD_FRAME


@pytest.mark.slow
def test_pose_writes_its_frame_and_says_the_orientation_is_ambiguous(lab, truth, tmp_path, capsys):
    a, b = lab.calibration_frames[1]
    out = tmp_path / "pose.json"
    code = main(["pose", str(a), str(b), "--output", str(out)])
    record = json.loads(out.read_text())
    err = capsys.readouterr().err
    assert code == (0 if record["accepted"] else 1)
    assert record["frame"] == WORLD_FRAME and record["units"] == {"length": "mm"}
    T = np.asarray(record["T_carm_transducer"])
    half = record["half_turn"]
    assert half["symmetric"] is True and "ambiguous by a half turn" in err
    np.testing.assert_allclose(half["axis_carm"], T[:3, 2])
    np.testing.assert_allclose(np.asarray(half["T_carm_transducer_half_turn"])[:3, :3], T[:3, :3] @ HALF_TURN)
    # whichever reading the estimate gave, one of the two is the truth's within a few degrees
    true_R = truth["station_T_carm_transducer"][1][:3, :3]
    angles = [np.degrees(np.arccos(np.clip((np.trace(true_R.T @ R) - 1) / 2, -1, 1)))
              for R in (T[:3, :3], T[:3, :3] @ HALF_TURN)]
    assert min(angles) < 5.0


@pytest.mark.parametrize("speed", ["0", "-50", "nan", "inf", "1500"])
def test_a_speed_that_is_no_speed_is_refused_before_the_plan_even_in_a_dry_run(speed, calibration_file, tmp_path,
                                                                               capsys):
    code, summary, written = _target(capsys, calibration_file, tmp_path / "t.json", "--target=0,0,0",
                                     f"--speed-mm-s={speed}")
    assert code == 2 and written is None and summary["bad_input"] is True
    assert summary["error"].startswith("--speed-mm-s must be a speed in mm/s, > 0 and at most 1000")


def test_the_speed_is_recorded_and_a_refused_pose_record_is_not_planned_with(lab, truth, calibration_file, tmp_path,
                                                                             capsys):
    x, y, z = lab.target_mm
    code, summary, written = _target(capsys, calibration_file, tmp_path / "t.json", f"--target={x},{y},{z}",
                                     "--speed-mm-s", "20")
    assert code == 0 and summary["speed_mm_s"] == written["speed_mm_s"] == 20.0
    record = tmp_path / "refused.json"
    record.write_text(json.dumps({"T_carm_transducer": np.asarray(truth["cine_T_carm_transducer"][0]).tolist(),
                                  "accepted": False, "verdict": {"reasons": ["view A: body RMS 4.1 px > 2.5 px"]}}))
    code, summary, written = _target(capsys, calibration_file, tmp_path / "r.json", f"--target={x},{y},{z}",
                                     "--pose", str(record))
    assert code == 2 and written is None
    assert summary["error"] == (f"--pose {str(record)!r} is a pose its verdict refused (view A: body RMS 4.1 px > "
                                "2.5 px): its orientation is not to be planned with; pose again")


def test_a_target_that_looks_like_metres_is_refused_unless_its_unit_is_named(lab, calibration_file, tmp_path,
                                                                              capsys):
    """A target within 1 mm of the isocentre on every axis (the lab's target typed in metres) is
    refused, naming the reading in mm; with --target-unit m it plans as the same point in mm, with
    --target-unit mm it plans as typed, and the isocentre itself (0, 0, 0) is never refused."""
    in_m = [float(v) / 1000.0 for v in lab.target_mm]
    metres = f"--target={','.join(map(repr, in_m))}"
    code, summary, written = _target(capsys, calibration_file, tmp_path / "m.json", metres)
    assert code == 2 and written is None and summary["bad_input"] is True
    assert "lies within 1 mm of the isocentre on every axis: it looks like metres" in summary["error"]
    assert f"({','.join(f'{1000.0 * v:g}' for v in in_m)} mm?)" in summary["error"]
    x, y, z = lab.target_mm
    code, _, as_mm = _target(capsys, calibration_file, tmp_path / "mm.json", f"--target={x},{y},{z}")
    code_m, summary_m, as_m = _target(capsys, calibration_file, tmp_path / "m2.json", metres, "--target-unit", "m")
    assert code == code_m == 0 and as_mm["target_unit_given"] == "mm" and as_m["target_unit_given"] == "m"
    np.testing.assert_allclose(as_m["plan"]["target_mm"], lab.target_mm, atol=1e-9)
    np.testing.assert_allclose(as_m["plan"]["target_mm"], as_mm["plan"]["target_mm"], atol=1e-9)
    np.testing.assert_allclose(summary_m["target_mm"], lab.target_mm, atol=1e-9)
    code, _, typed = _target(capsys, calibration_file, tmp_path / "t.json", metres, "--target-unit", "mm")
    assert code == 0 and typed["target_unit_given"] == "mm"
    np.testing.assert_allclose(typed["plan"]["target_mm"], in_m, atol=1e-12)
    code, _, _ = _target(capsys, calibration_file, tmp_path / "o.json", "--target=0,0,0")
    assert code == 0
    code, summary, written = _target(capsys, calibration_file, tmp_path / "v.json", "--target-voxel", "36,37,31",
                                     "--cbct", str(lab.cbct), "--target-unit", "m")
    assert code == 2 and written is None and summary["error"].startswith("--target-unit m gives the unit of --target")


def test_a_pose_of_another_study_than_the_calibrations_is_refused(lab, truth, calibration_file, tmp_path, capsys):
    """A pose record acquired in another study than the calibration's stations (a calibration of
    another session, or another dataset) is refused naming both studies; one of the calibration's
    study plans, and a calibration or a pose that names no study is not judged by it."""
    x, y, z = lab.target_mm
    calibration = json.loads(calibration_file.read_text())
    calibration["study_instance_uids"] = ["1.2.826.0.1.3680043.8.498.1"]
    with_study = tmp_path / "calibration.json"
    with_study.write_text(json.dumps(calibration))
    pose = {"T_carm_transducer": np.asarray(truth["cine_T_carm_transducer"][0]).tolist(), "accepted": True,
            "verdict": {"reasons": []}}
    outcomes = {}
    for name, study in (("other", "1.2.826.0.1.3680043.8.498.2"), ("same", "1.2.826.0.1.3680043.8.498.1"),
                        ("none", None)):
        record = tmp_path / f"{name}.json"
        record.write_text(json.dumps({**pose, "study_instance_uid": study}))
        outcomes[name] = _target(capsys, with_study, tmp_path / f"{name}-plan.json", f"--target={x},{y},{z}",
                                 "--pose", str(record))
    code, summary, written = outcomes["other"]
    assert code == 2 and written is None
    assert summary["error"].startswith(f"--pose {str(tmp_path / 'other.json')!r} was acquired in study "
                                       "1.2.826.0.1.3680043.8.498.2, --calibration")
    assert "in 1.2.826.0.1.3680043.8.498.1: a calibration holds only while" in summary["error"]
    assert outcomes["same"][0] == outcomes["none"][0] == 0
    code, _, _ = _target(capsys, calibration_file, tmp_path / "p.json", f"--target={x},{y},{z}", "--pose",
                         str(tmp_path / "other.json"))  # the calibration names no study
    assert code == 0
