"""histostudy.study.your_data.moving_cine: the robot's tour of the study's margin points is smooth, keeps its
speed limit and lands on the margins; the cine is single-frame DICOM XA timed at the frame rate,
its truth kept beside it and consistent with the robot's chain, and the same seed writes the same
bytes. Small views and a coarse render model keep it quick (the receiver's run is in
test_study_moving_cine_live.py)."""

import json

import numpy as np
import pydicom
import pytest

from histostudy.imaging import default_biplane, load_views
from histostudy.lab.pairing import frame_times, posix_seconds
from histostudy.lab.xray_objects import decode_xray_object
from histostudy.study.pose.geometry import margin_positions
from histostudy.study.your_data.moving_cine import MARGIN_TOUR, T0, load_moving_cine, robot_path, write_moving_cine
from histostudy.transducer import pose_facing

SMALL = dict(views=default_biplane(shape=(96, 124), pixel_mm=3.08), render_spacing_mm=0.5)


@pytest.fixture(scope="module")
def path():
    return robot_path(pose_facing(), 60.0, radius_mm=12.5, max_speed_mm_s=10.0, dwell_s=1.0)


def test_the_tour_visits_the_margins_smoothly_within_the_speed_limit(path):
    T = pose_facing()
    margins = {name: P[:3, 3] for name, P in margin_positions(T, 12.5).items()}
    # the order of the study's margins, repeated, back on the centre at the end, and at least 60 s
    assert path.names[:len(MARGIN_TOUR)] == MARGIN_TOUR and path.names[-1] == "centre"
    assert set(path.names) == set(margins) and path.duration_s >= 60.0
    # each leg ends exactly on its waypoint, which is the margin point, and holds it for the dwell
    ends = path.leg_start_s + path.leg_s
    arrived, _, _ = path.at(ends)
    np.testing.assert_allclose(arrived, [margins[n] for n in path.names[1:]], atol=1e-9)
    held, speed_held, _ = path.at(np.r_[ends[:-1] + 0.5, 0.5])
    np.testing.assert_allclose(held, np.r_[path.waypoints_mm[1:-1], path.waypoints_mm[:1]], atol=1e-9)
    assert np.all(speed_held == 0)
    # sampled at 1 kHz: speed <= 10 mm/s, reached on the legs; speed and position continuous
    t = np.arange(0.0, path.duration_s, 1e-3)
    points, speed, _ = path.at(t)
    assert speed.max() <= 10.0 + 1e-9 and speed.max() > 9.99
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    np.testing.assert_allclose(step / 1e-3, 0.5 * (speed[1:] + speed[:-1]), atol=2e-3)
    assert np.abs(np.diff(speed)).max() / 1e-3 < 1.5 * 5.78 * 10.0 / path.leg_s.min()  # bounded acceleration
    # the orientation never changes
    poses = path.poses(t[::500])
    np.testing.assert_allclose(poses[:, :3, :3], np.broadcast_to(T[:3, :3], poses[:, :3, :3].shape), atol=0)


@pytest.mark.parametrize("kwargs, message", [
    ({"duration_s": 0}, "duration_s must be a finite number > 0 s, got 0"),
    ({"radius_mm": -1.0}, "radius_mm must be a finite number > 0 mm"),
    ({"max_speed_mm_s": float("nan")}, "max_speed_mm_s must be a finite number > 0 mm/s"),
    ({"dwell_s": -0.5}, r"dwell_s must be a finite pause >= 0 s, got -0.5"),
])
def test_robot_path_refuses_bad_arguments_by_name(kwargs, message):
    args = {"duration_s": 10.0, **kwargs}
    with pytest.raises(ValueError, match=message):
        robot_path(pose_facing(), args.pop("duration_s"), **args)


def test_write_moving_cine_refuses_bad_arguments_by_name(tmp_path):
    with pytest.raises(ValueError, match="fps must be a finite number > 0 frames/s"):
        write_moving_cine(tmp_path, seed=1, fps=0.0)
    with pytest.raises(ValueError, match="seed must be an integer >= 0, got -1"):
        write_moving_cine(tmp_path, seed=-1)
    with pytest.raises(ValueError, match="must give at least one frame"):
        write_moving_cine(tmp_path, seed=1, duration_s=0.01, fps=7.5)


@pytest.fixture(scope="module")
def cine(tmp_path_factory):
    return write_moving_cine(tmp_path_factory.mktemp("cine"), seed=4, duration_s=0.5, fps=7.5, **SMALL)


def test_the_cine_is_single_frame_xa_timed_at_the_frame_rate_with_its_truth_apart(cine):
    assert cine.n_frames == 4 and load_moving_cine(cine.folder).frames == cine.frames
    views = load_views(cine.views)
    for k, pair in enumerate(cine.frames):
        for path, view in zip(pair, views):
            ds = pydicom.dcmread(path)
            (when,), interval = frame_times(ds)
            assert interval is None and ds.SeriesDescription == view.name
            assert posix_seconds(when) - posix_seconds(T0) == pytest.approx(k / 7.5, abs=1e-6)
            assert cine.frame_at(when) == k
            (frame,) = decode_xray_object(ds, views)
            assert frame.view.name == view.name and np.isfinite(frame.image).all()
            assert "truth" not in ds.dir("")  # nothing of the truth travels with the frames
    truth = cine.read_truth()
    assert truth["T_carm_transducer"].shape == (4, 4, 4) and truth["time_s"].tolist() == cine.times_s.tolist()
    # the truth is the robot's chain: T_carm_base @ T_base_flange @ T_flange_transducer
    chain = truth["T_carm_base"] @ truth["T_base_flange"] @ truth["T_flange_transducer"]
    np.testing.assert_allclose(chain, truth["T_carm_transducer"], atol=1e-9)
    np.testing.assert_allclose(truth["focal_point_mm"], truth["T_carm_transducer"][:, :3, 3], atol=1e-12)
    assert truth["waypoint_names"][0] == "centre" and truth["radius_mm"] == 12.5
    manifest = json.loads(cine.manifest.read_text())
    assert manifest["fps"] == 7.5 and manifest["n_frames"] == 4 and manifest["truth"] == "truth.json"


def test_the_same_seed_writes_the_same_bytes(cine, tmp_path):
    again = write_moving_cine(tmp_path / "again", seed=4, duration_s=0.5, fps=7.5, **SMALL)
    for a, b in zip([p for pair in cine.frames for p in pair], [p for pair in again.frames for p in pair]):
        assert a.read_bytes() == b.read_bytes()
    assert cine.truth.read_bytes() == again.truth.read_bytes()
    other = write_moving_cine(tmp_path / "other", seed=5, duration_s=0.15, fps=7.5, **SMALL)
    assert other.frames[0][0].read_bytes() != cine.frames[0][0].read_bytes()
