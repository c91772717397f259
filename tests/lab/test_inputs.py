"""histostudy.lab.inputs: flange poses in the wrong unit (metres for mm, mm for metres, degrees for
radians) refused by name before any calibration, through load_flange_poses; every pose a UR5e can
take, in the stated units, accepted — the study's calibration stations and the arm's extremes."""

import json

import numpy as np
import pytest

from histostudy.geometry import make_transform
from histostudy.lab import check_flange_pose_units, load_flange_poses
from histostudy.lab.inputs import FLANGE_DISTANCE_MM, FLANGE_UNIT_SPLIT
from histostudy.robot import forward_kinematics, pose_from_transform
from histostudy.study.targeting._calibration import calibration_poses
from histostudy.study.targeting.setup import TargetingStudyConfig, draw_ground_truth

#: Joint angles (rad) where a UR5e's flange is nearest its base (elbow folded, wrist turned back)
#: and farthest from it (stretched up and out): found by minimising and maximising the distance.
NEAREST_JOINTS = (0.0, 0.0, -3.6902, -0.587, -np.pi, 0.0)
FARTHEST_JOINTS = (-1.8084, -np.pi / 2, 0.0, -0.7952, 1.3789, 0.0)


@pytest.fixture(scope="module")
def stations():
    """The flange poses (4x4, mm) of the study's calibration: those the generated lab dataset writes."""
    rng = np.random.default_rng(3)
    config = TargetingStudyConfig(n_experiments=1, background="none")
    return calibration_poses(rng, config, draw_ground_truth(rng, config))


def _write(folder, name, data):
    path = folder / name
    path.write_text(json.dumps(data))
    return path


def _as_metres(flanges):
    out = []
    for F in flanges:
        F = np.array(F, dtype=np.float64)
        F[:3, 3] /= 1000.0
        out.append(F.tolist())
    return out


def test_the_distance_bounds_are_the_ur5e_kinematics():
    near, far = (np.linalg.norm(forward_kinematics(q)[:3, 3]) for q in (NEAREST_JOINTS, FARTHEST_JOINTS))
    assert near == pytest.approx(FLANGE_DISTANCE_MM[0], abs=0.05) and far == pytest.approx(FLANGE_DISTANCE_MM[1],
                                                                                           abs=0.05)
    q = np.random.default_rng(0).uniform(-2 * np.pi, 2 * np.pi, (2000, 6))
    d = np.array([np.linalg.norm(forward_kinematics(x)[:3, 3]) for x in q])
    assert FLANGE_DISTANCE_MM[0] - 0.01 <= d.min() and d.max() <= FLANGE_DISTANCE_MM[1] + 0.01
    # the split lies between the farthest flange in metres and the nearest in millimetres
    assert FLANGE_DISTANCE_MM[1] / 1000 < FLANGE_UNIT_SPLIT < FLANGE_DISTANCE_MM[0]


def test_plausible_flange_poses_are_accepted_in_both_forms(tmp_path, stations):
    mm = _write(tmp_path, "mm.json", {"T_base_flange": [F.tolist() for F in stations]})
    ur = _write(tmp_path, "ur.json", {"ur_pose": [pose_from_transform(F) for F in stations]})
    for path in (mm, ur):
        np.testing.assert_allclose(load_flange_poses(path), stations, atol=1e-9)


def test_the_ur5e_extremes_are_accepted_in_both_forms(tmp_path):
    extremes = [forward_kinematics(q) for q in (NEAREST_JOINTS, FARTHEST_JOINTS)]
    # a pose in between; as a UR pose turned by just under a full turn, an unusual but valid axis-angle
    between = make_transform(np.eye(3), [0.0, 300.0, 400.0])
    poses = [pose_from_transform(F) for F in extremes] + [[0.0, 0.3, 0.4, 0.0, 0.0, 2 * np.pi - 0.01]]
    check_flange_pose_units({"ur_pose": poses}, "ur.json")
    check_flange_pose_units({"T_base_flange": [F.tolist() for F in [*extremes, between]]}, "mm.json")
    path = _write(tmp_path, "ur.json", {"ur_pose": [pose_from_transform(F) for F in extremes]})
    np.testing.assert_allclose(load_flange_poses(path), extremes, atol=1e-9)


def test_transforms_in_metres_are_named_as_metres(tmp_path, stations):
    path = _write(tmp_path, "metres.json", {"T_base_flange": _as_metres(stations)})
    with pytest.raises(ValueError, match=r"metres\.json'.*T_base_flange translations are all under 6 .*look like "
                                         r"metres.*multiply them by 1000, or give the poses as ur_pose"):
        load_flange_poses(path)
    # one station in metres among millimetres: that station named
    mixed = [F.tolist() for F in stations]
    mixed[1] = _as_metres([stations[1]])[0]
    with pytest.raises(ValueError, match=r"T_base_flange\[1\]: translations of norm \[0\.\d+\].*look like metres"):
        load_flange_poses(_write(tmp_path, "mixed.json", {"T_base_flange": mixed}))


def test_ur_poses_in_millimetres_or_degrees_are_named(tmp_path, stations):
    poses = [pose_from_transform(F) for F in stations]
    in_mm = [[*(1000 * np.array(p[:3])).tolist(), *p[3:]] for p in poses]
    with pytest.raises(ValueError, match=r"mm\.json'.*ur_pose translations \[x, y, z\] are all over 6 .*look like "
                                         r"millimetres.*divide x, y, z by 1000"):
        load_flange_poses(_write(tmp_path, "mm.json", {"ur_pose": in_mm}))
    in_degrees = [[*p[:3], *np.degrees(p[3:]).tolist()] for p in poses]
    n = len(poses)
    with pytest.raises(ValueError, match=rf"deg\.json'.*ur_pose\[{', '.join(map(str, range(n)))}\]: rotation vectors "
                                         r".*more than a full turn.*look like degrees; multiply rx, ry, rz by pi/180"):
        load_flange_poses(_write(tmp_path, "deg.json", {"ur_pose": in_degrees}))
    # both at once: both named; one station beyond the reach: that station named
    both = [[*a[:3], *b[3:]] for a, b in zip(in_mm, in_degrees)]
    with pytest.raises(ValueError, match=r"look like millimetres.*; ur_pose\[.*look like degrees"):
        load_flange_poses(_write(tmp_path, "both.json", {"ur_pose": both}))
    one = list(poses)
    one[2] = in_mm[2]
    with pytest.raises(ValueError, match=r"ur_pose\[2\]: translations .* beyond a UR5e's reach"):
        load_flange_poses(_write(tmp_path, "one.json", {"ur_pose": one}))


def test_the_transforms_are_read_when_both_forms_are_given(tmp_path, stations):
    """The generated dataset's file holds both; the transforms are what is read and judged."""
    data = {"T_base_flange": [F.tolist() for F in stations], "ur_pose": [pose_from_transform(F) for F in stations],
            "units": {"T_base_flange": "mm", "ur_pose": "m, axis-angle rad"}}
    np.testing.assert_allclose(load_flange_poses(_write(tmp_path, "both.json", data)), stations, atol=1e-9)
    data["T_base_flange"] = _as_metres(stations)
    with pytest.raises(ValueError, match="look like metres"):
        load_flange_poses(_write(tmp_path, "both_m.json", data))
