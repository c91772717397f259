"""``histostudy calibrate`` and ``histostudy pose`` check every input before the first pose estimate
(issue 38): each bad input is refused with exit status 2 and a message naming the flag, the file or
the unit, nothing is written and no pose work is done (the estimate is replaced by one that fails
the test if called); plausible inputs get through to the pose work, and a calibration on pose
records runs to its end with the flange poses in either form."""

import dataclasses
import datetime as dt
import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pydicom
import pytest

from histostudy.cli import main
from histostudy.imaging import View, default_biplane, save_views, write_xa
from histostudy.imaging.io._xa import xa_dataset
from histostudy.robot import pose_from_transform
from histostudy.study.targeting._calibration import calibration_poses
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth

SHAPE = (96, 124)


class PoseWork(Exception):
    """Raised by the stand-in estimate: the checks let the inputs through to the pose work."""


@pytest.fixture(autouse=True)
def no_pose_work(monkeypatch):
    """Every way to a pose estimate raises PoseWork, so a check that failed to stop bad input
    shows as an error of its own rather than as a late refusal."""
    def estimate(*args, **kwargs):
        raise PoseWork("the pose estimate was reached")

    for target in ("histostudy.cli.lab._calibrate.estimate_from_files", "histostudy.cli.lab._pose.estimate_from_files",
                   "histostudy.pose.pose_from_files"):
        monkeypatch.setattr(target, estimate)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Four stations of single-frame XA pairs (small views; their pixels never posed here), the
    study's flange poses in both forms, and the true pose record of each station."""
    folder = tmp_path_factory.mktemp("inputs")
    views = default_biplane(shape=SHAPE, pixel_mm=3.08)
    save_views(folder / "views.json", views)
    rng = np.random.default_rng(3)
    config = TargetingStudyConfig(n_experiments=1, background="none")
    truth = draw_ground_truth(rng, config)
    flanges = calibration_poses(rng, config, truth)
    stations, records = [], []
    for k, F in enumerate(flanges):
        station = folder / f"station_{k}"
        station.mkdir()
        for view in views:
            write_xa(station / f"{view.name}.dcm", view, np.full(SHAPE, 2000, np.uint16), uid_seed=f"station {k}",
                     study_uid_seed="one procedure", acquisition_time=dt.datetime(2020, 1, 1, 0, k))
        T = truth.T_carm_transducer(F)
        record = folder / f"pose_{k}.json"
        record.write_text(json.dumps({"T_carm_transducer": T.tolist(), "focal_point_mm": T[:3, 3].tolist(),
                                      "accepted": True}))
        stations.append(str(station))
        records.append(str(record))
    both = folder / "flange_poses.json"
    both.write_text(json.dumps({"T_base_flange": [F.tolist() for F in flanges],
                                "ur_pose": [pose_from_transform(F) for F in flanges]}))
    ur = folder / "ur_pose.json"
    ur.write_text(json.dumps({"ur_pose": [pose_from_transform(F) for F in flanges]}))
    return SimpleNamespace(folder=folder, views=views, stations=stations, records=records, flanges=flanges,
                           flange_file=str(both), ur_file=str(ur))


def _run(argv, capsys):
    code = main(argv)
    return code, capsys.readouterr().err


def _calibrate(lab, tmp_path, capsys, *stations, flanges=None, extra=()):
    """``histostudy calibrate``'s exit status and stderr; asserts that nothing was written."""
    out = tmp_path / "calibration.json"
    code, err = _run(["calibrate", *(stations or lab.stations), "--flange-poses", flanges or lab.flange_file,
                      *extra, "--output", str(out)], capsys)
    assert not out.exists()
    return code, err


def _copy_station(lab, tmp_path, name="bad"):
    station = tmp_path / name
    shutil.copytree(lab.stations[0], station)
    return station


def test_stations_that_are_missing_empty_or_unreadable_are_named(lab, tmp_path, capsys):
    missing = str(tmp_path / "station_9")
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], missing)
    assert code == 2 and f"station '{missing}': no such folder" in err
    (tmp_path / "empty").mkdir()
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], str(tmp_path / "empty"))
    assert code == 2 and "station folder" in err and "empty' holds no frame files" in err
    frame = f"{lab.stations[0]}/A.dcm"
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], frame)
    assert code == 2 and f"station '{frame}' is a frame file: give the station's folder" in err
    (tmp_path / "pose.json").write_text("{not json")
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], str(tmp_path / "pose.json"))
    assert code == 2 and "pose record" in err and "pose.json' is not JSON" in err
    (tmp_path / "bare.json").write_text(json.dumps({"T_carm_transducer": np.eye(4).tolist(), "accepted": True}))
    code, err = _calibrate(lab, tmp_path, capsys, *lab.records[:3], str(tmp_path / "bare.json"))
    assert code == 2 and "bare.json' lacks 'focal_point_mm'" in err


def test_the_station_count_must_match_the_flange_poses_and_reach_three(lab, tmp_path, capsys):
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3])
    assert code == 2 and f"--flange-poses '{lab.flange_file}' holds 4 flange poses for the 3 stations given" in err
    two = tmp_path / "two.json"
    two.write_text(json.dumps({"T_base_flange": [F.tolist() for F in lab.flanges[:2]]}))
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:2], flanges=str(two))
    assert code == 2 and "calibrate needs at least 3 stations" in err and "got 2" in err


def test_flange_poses_in_the_wrong_unit_are_named(lab, tmp_path, capsys):
    metres = [np.array(F) for F in lab.flanges]
    for F in metres:
        F[:3, 3] /= 1000.0
    poses = [pose_from_transform(F) for F in lab.flanges]
    files = {"metres.json": ({"T_base_flange": [F.tolist() for F in metres]}, "look like metres"),
             "mm.json": ({"ur_pose": [[*(1000 * np.array(p[:3])).tolist(), *p[3:]] for p in poses]},
                         "look like millimetres"),
             "degrees.json": ({"ur_pose": [[*p[:3], *np.degrees(p[3:]).tolist()] for p in poses]},
                              "look like degrees")}
    for name, (data, unit) in files.items():
        (tmp_path / name).write_text(json.dumps(data))
        code, err = _calibrate(lab, tmp_path, capsys, flanges=str(tmp_path / name))
        assert code == 2 and f"--flange-poses: flange poses file '{tmp_path / name}'" in err and unit in err, err
    (tmp_path / "scalar.json").write_text(json.dumps({"T_base_flange": 3}))
    code, err = _calibrate(lab, tmp_path, capsys, flanges=str(tmp_path / "scalar.json"))
    assert code == 2 and "scalar.json': expected a list of poses, one per station" in err


def test_residual_bounds_are_checked_before_the_poses(lab, tmp_path, capsys):
    for flag in ("--max-focal-residual-mm", "--max-rotation-residual-deg"):
        code, err = _calibrate(lab, tmp_path, capsys, extra=[f"{flag}=-1"])
        assert code == 2 and f"{flag} -1.0: expected a finite bound > 0" in err


def test_a_bad_nominal_mount_is_named(lab, tmp_path, capsys):
    missing = str(tmp_path / "mount.json")
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--nominal-mount", missing])
    assert code == 2 and f"--nominal-mount '{missing}': no such file" in err
    (tmp_path / "mount.json").write_text("[1, 2")
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--nominal-mount", missing])
    assert code == 2 and f"--nominal-mount '{missing}' is not JSON" in err
    (tmp_path / "mount.json").write_text(json.dumps({"T_flange_transducer": np.diag([2.0, 1, 1, 1]).tolist()}))
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--nominal-mount", missing])
    assert code == 2 and f"--nominal-mount '{missing}': T_flange_transducer" in err


def test_truncated_or_foreign_frame_files_are_named_with_their_path(lab, tmp_path, capsys):
    station = _copy_station(lab, tmp_path)
    data = (station / "B.dcm").read_bytes()
    (station / "B.dcm").write_bytes(data[: len(data) // 2])
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], str(station))
    assert code == 2 and f"DICOM file '{station / 'B.dcm'}' is truncated or corrupt" in err
    (station / "B.dcm").write_bytes(data[:100])
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], str(station))
    assert code == 2 and f"DICOM file '{station / 'B.dcm'}' could not be read as DICOM" in err
    assert "force=True" not in err  # pydicom's advice names a Python argument
    (station / "B.dcm").write_text("notes, not an image")
    code, err = _run(["pose", str(station / "A.dcm"), str(station / "B.dcm"), "--output",
                      str(tmp_path / "p.json")], capsys)
    assert code == 2 and f"DICOM file '{station / 'B.dcm'}' could not be read as DICOM" in err
    assert not (tmp_path / "p.json").exists()


def test_a_frame_without_geometry_names_the_views_flag_and_a_matching_views_file_gets_through(lab, tmp_path, capsys):
    station = _copy_station(lab, tmp_path)
    ds = xa_dataset(lab.views[0], np.full(SHAPE, 2000, np.uint16))
    del ds.PositionerPrimaryAngle
    partner = pydicom.dcmread(station / "B.dcm", stop_before_pixels=True)
    for keyword in ("StudyInstanceUID", "AcquisitionDateTime", "AcquisitionDate", "AcquisitionTime"):
        if keyword in partner:  # one acquisition with its station's B
            setattr(ds, keyword, partner[keyword].value)
    ds.save_as(station / "A.dcm", enforce_file_format=True)
    code, err = _calibrate(lab, tmp_path, capsys, *lab.stations[:3], str(station))
    assert code == 2 and "A.dcm lacks PositionerPrimaryAngle (0018,1510)" in err and "(--views FILE)" in err
    with pytest.raises(PoseWork):
        main(["calibrate", *lab.stations[:3], str(station), "--flange-poses", lab.flange_file, "--views",
              str(lab.folder / "views.json"), "--output", str(tmp_path / "c.json")])


def test_a_views_file_that_does_not_fit_is_named(lab, tmp_path, capsys):
    (tmp_path / "views.json").write_text("{broken")
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--views", str(tmp_path / "views.json")])
    assert code == 2 and f"--views '{tmp_path / 'views.json'}' is not a views file" in err
    save_views(tmp_path / "one.json", [dataclasses.replace(lab.views[0], name="X")])
    frames = [f"{lab.stations[0]}/A.dcm", f"{lab.stations[0]}/B.dcm"]
    code, err = _run(["pose", *frames, "--views", str(tmp_path / "one.json"), "--output", str(tmp_path / "p.json")],
                     capsys)
    assert code == 2 and f"--views '{tmp_path / 'one.json'}' holds 1 views for 2 frame files" in err
    assert "['A.dcm', 'B.dcm']" in err and not (tmp_path / "p.json").exists()
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--views", str(tmp_path / "none.json")])
    assert code == 2 and f"--views '{tmp_path / 'none.json'}': no such file" in err


def test_bad_transducer_meshes_are_named(lab, tmp_path, capsys):
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--transducer", str(tmp_path / "none")])
    assert code == 2 and f"--transducer '{tmp_path / 'none'}': no such folder" in err
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "transducer.stl").write_text("solid broken\n")
    code, err = _calibrate(lab, tmp_path, capsys, extra=["--transducer", str(tmp_path / "meshes")])
    assert code == 2 and f"--transducer '{tmp_path / 'meshes'}': " in err and "transducer.stl" in err


def test_a_cine_needs_a_frame_index_it_holds(lab, tmp_path, capsys):
    station = tmp_path / "cine"
    station.mkdir()
    for view in lab.views:
        write_xa(station / f"{view.name}.dcm", view, np.full((3, *SHAPE), 2000, np.uint16))
    stations = [str(station), *lab.stations[:3]]
    code, err = _calibrate(lab, tmp_path, capsys, *stations)
    assert code == 2 and "cine/A.dcm' holds 3 frames (a cine): pick one with --frame-index" in err
    code, err = _calibrate(lab, tmp_path, capsys, *stations, extra=["--frame-index", "5"])
    assert code == 2 and "--frame-index 5:" in err and "cine/A.dcm' holds 3 frame(s), 0 to 2" in err
    code, err = _calibrate(lab, tmp_path, capsys, *stations, extra=["--frame-index", "-1"])
    assert code == 2 and "--frame-index -1: expected a frame index >= 0" in err
    # --frame-index 2 picks one of the cine's 3 frames, but the other stations hold one frame each
    code, err = _calibrate(lab, tmp_path, capsys, *stations, extra=["--frame-index", "2"])
    assert code == 2 and "station_0/A.dcm' holds 1 frame(s), 0 to 0" in err


def test_frames_of_another_size_than_their_views_need_resample(lab, tmp_path, capsys):
    for k, name in enumerate("AB"):
        np.save(tmp_path / f"{name}.npy", np.full((48, 62), 1.0 + k))
    frames = [str(tmp_path / "A.npy"), str(tmp_path / "B.npy")]
    views = ["--views", str(lab.folder / "views.json")]
    code, err = _run(["pose", *frames, *views, "--output", str(tmp_path / "p.json")], capsys)
    assert code == 2 and "A.npy' holds a 48 x 62 image, its view 'A' in --views expects 96 x 124" in err
    assert "give --resample" in err and not (tmp_path / "p.json").exists()
    with pytest.raises(PoseWork):
        main(["pose", *frames, *views, "--resample", "--output", str(tmp_path / "p.json")])


def test_pose_names_missing_folders_and_frames_without_geometry(lab, tmp_path, capsys):
    a = f"{lab.stations[0]}/A.dcm"
    out = str(tmp_path / "p.json")
    code, err = _run(["pose", a, str(tmp_path / "C.dcm"), "--output", out], capsys)
    assert code == 2 and f"FRAMES '{tmp_path / 'C.dcm'}': no such file" in err
    code, err = _run(["pose", a, lab.stations[1], "--output", out], capsys)
    assert code == 2 and f"FRAMES '{lab.stations[1]}' is a folder, not a frame file" in err
    np.save(tmp_path / "B.npy", np.ones(SHAPE))
    code, err = _run(["pose", a, str(tmp_path / "B.npy"), "--output", out], capsys)
    assert code == 2 and "B.npy' carries no geometry (not DICOM): give the frames' views with --views FILE" in err
    (tmp_path / "B.txt").write_text("x")
    code, err = _run(["pose", a, str(tmp_path / "B.txt"), "--output", out], capsys)
    assert code == 2 and "B.txt': not a frame file" in err
    assert not (tmp_path / "p.json").exists()
    with pytest.raises(PoseWork):
        main(["pose", a, f"{lab.stations[0]}/B.dcm", "--output", out])


def test_plausible_inputs_get_through_to_the_pose_work(lab, tmp_path):
    for flanges in (lab.flange_file, lab.ur_file):
        with pytest.raises(PoseWork):
            main(["calibrate", *lab.stations, "--flange-poses", flanges, "--output", str(tmp_path / "c.json")])
    assert not (tmp_path / "c.json").exists()


def test_a_calibration_on_pose_records_runs_with_either_form_and_refused_stations_exit_1(lab, tmp_path, capsys):
    for name, flanges in (("transforms", lab.flange_file), ("ur", lab.ur_file)):
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", *lab.records, "--flange-poses", flanges, "--output", str(out)]) == 0
        assert json.loads(out.read_text())["summary"]["max_focal_residual_mm"] < 1e-3
    refused = tmp_path / "refused.json"
    refused.write_text(json.dumps({**json.loads(Path(lab.records[1]).read_text()), "accepted": False}))
    records = [lab.records[0], str(refused), *lab.records[2:]]
    code, err = _calibrate(lab, tmp_path, capsys, *records)
    assert code == 1 and f"the pose verdict refused station(s) ['{refused}']" in err and "--exclude-refused" in err
    assert main(["calibrate", *records, "--flange-poses", lab.flange_file, "--exclude-refused", "--output",
                 str(tmp_path / "three.json")]) == 0
    assert json.loads((tmp_path / "three.json").read_text())["used_stations"] == [records[0], *records[2:]]


@pytest.mark.slow
def test_the_generated_lab_datasets_flange_file_is_accepted_in_both_forms(tmp_path):
    from histostudy.lab import load_flange_poses
    from histostudy.study.your_data.lab_dataset import write_lab_dataset

    generated = write_lab_dataset(tmp_path / "lab", seed=9, n_cine_frames=1,
                                  views=default_biplane(shape=SHAPE, pixel_mm=3.08))
    data = json.loads(generated.flange_poses.read_text())
    (tmp_path / "ur.json").write_text(json.dumps({"ur_pose": data["ur_pose"]}))
    np.testing.assert_allclose(load_flange_poses(tmp_path / "ur.json"), load_flange_poses(generated.flange_poses),
                               atol=1e-9)
    stations = [str(a.parent) for a, _ in generated.calibration_frames]
    for flanges in (str(generated.flange_poses), str(tmp_path / "ur.json")):
        with pytest.raises(PoseWork):
            main(["calibrate", *stations, "--flange-poses", flanges, "--transducer",
                  str(generated.folder / "transducer"), "--output", str(tmp_path / "c.json")])


def test_frames_that_are_not_one_acquisition_of_the_planes_are_refused_naming_why(lab, tmp_path, capsys):
    """The same file twice, its copy, one instance re-encoded, planes of two studies or taken a minute
    apart: each refused before the pose (issue 56), and a pair within --max-pair-gap-s gets through."""
    a, b = Path(lab.stations[0]) / "A.dcm", Path(lab.stations[0]) / "B.dcm"
    out = ["--output", str(tmp_path / "p.json")]
    code, err = _run(["pose", str(a), str(a), *out], capsys)
    assert code == 2 and f"FRAMES '{a}' is '{a}' again (the same file): a pose needs one frame per plane" in err
    shutil.copy(a, tmp_path / "B.dcm")
    code, err = _run(["pose", str(a), str(tmp_path / "B.dcm"), *out], capsys)
    assert code == 2 and "again (the same bytes)" in err
    same_instance = pydicom.dcmread(a)
    same_instance.InstanceNumber = 7
    same_instance.save_as(tmp_path / "B.dcm")
    code, err = _run(["pose", str(a), str(tmp_path / "B.dcm"), *out], capsys)
    assert code == 2 and f"are one X-ray object (SOPInstanceUID {same_instance.SOPInstanceUID})" in err
    other_study = pydicom.dcmread(b)
    other_study.StudyInstanceUID = "1.2.826.0.1.3680043.8.498.9"
    other_study.save_as(tmp_path / "B.dcm")
    code, err = _run(["pose", str(a), str(tmp_path / "B.dcm"), *out], capsys)
    study_a = pydicom.dcmread(a, stop_before_pixels=True).StudyInstanceUID
    assert code == 2 and f"'{a}' (study {study_a}) and '{tmp_path / 'B.dcm'}' (study {other_study.StudyInstanceUID})" \
        in err
    assert "are of different studies: not one acquisition of the planes" in err
    other_station = Path(lab.stations[1]) / "B.dcm"  # the same procedure's study, a minute later
    code, err = _run(["pose", str(a), str(other_station), *out], capsys)
    assert code == 2 and "were taken 60 s apart, more than --max-pair-gap-s 10" in err
    later = pydicom.dcmread(b)
    later.AcquisitionDateTime = "20200101000100.000000"  # a minute after A
    later.save_as(tmp_path / "B.dcm")
    code, err = _run(["pose", str(a), str(tmp_path / "B.dcm"), *out], capsys)
    assert code == 2 and "were taken 60 s apart, more than --max-pair-gap-s 10" in err
    assert not (tmp_path / "p.json").exists()
    with pytest.raises(PoseWork):
        main(["pose", str(a), str(tmp_path / "B.dcm"), "--max-pair-gap-s", "90", *out])
    code, err = _run(["pose", str(a), str(b), "--max-pair-gap-s", "nan", *out], capsys)
    assert code == 2 and "--max-pair-gap-s must be a finite number of seconds >= 0, got nan" in err


def test_views_that_the_files_gantry_tags_contradict_are_named(lab, tmp_path, capsys):
    """A views file of another geometry (plane A turned 10 degrees) than the DICOM files' tags record
    is refused naming the view, the file and the distance (issue 56), as the receiver refuses it."""
    g = lab.views[0].gantry
    turned = [View.from_gantry(g["primary_deg"] + 10.0, g["secondary_deg"],
                               source_isocenter_mm=g["source_isocenter_mm"],
                               source_detector_mm=g["source_detector_mm"], shape=lab.views[0].shape,
                               pixel_mm=lab.views[0].pixel_mm, name="A"), lab.views[1]]
    save_views(tmp_path / "turned.json", turned)
    frames = [f"{lab.stations[0]}/A.dcm", f"{lab.stations[0]}/B.dcm"]
    distance = lab.views[0].projection_distance_mm(turned[0])
    code, err = _run(["pose", *frames, "--views", str(tmp_path / "turned.json"), "--output", str(tmp_path / "p.json")],
                     capsys)
    assert code == 2 and distance > 5.0 and not (tmp_path / "p.json").exists()
    said = re.search(rf"view 'A' and the gantry tags of '{re.escape(frames[0])}' project ([0-9.]+) mm apart at the "
                     r"isocentre \(> 5 mm\)", err)
    assert said and float(said.group(1)) == pytest.approx(distance, abs=0.2)
    with pytest.raises(PoseWork):  # the views the files were written with
        main(["pose", *frames, "--views", str(lab.folder / "views.json"), "--output", str(tmp_path / "p.json")])


def test_flange_poses_of_another_session_are_a_refusal_that_names_the_flange_file(lab, tmp_path, capsys):
    """The stations' true pose records with the flange poses in another order (as another session's
    file would be): the residuals refuse the calibration (exit 1) and the message names the file."""
    other = tmp_path / "other_flanges.json"
    other.write_text(json.dumps({"T_base_flange": [F.tolist() for F in lab.flanges[::-1]]}))
    code, err = _calibrate(lab, tmp_path, capsys, *lab.records, flanges=str(other))
    assert code == 1 and "residuals exceed the stated bound" in err
    assert f"(--flange-poses '{other}': the robot's poses at these stations, in the order given?)" in err
