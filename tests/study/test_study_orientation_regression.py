"""Notebook 03's study module: per-frame angles against the true pose, the §III statistics, the figure."""

import numpy as np
import pytest

from histostudy.imaging import Frame, View
from histostudy.learning import angles_from_direction, beam_direction_of_pose, wrap_angle
from histostudy.study import orientation_regression as study
from histostudy.transducer import pose_facing


def _frames(n=12, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        view = View.from_gantry(float(rng.uniform(-60, 60)), shape=(24, 32))
        T = pose_facing(rng.normal(size=3), rng.uniform(-20, 20, 3), float(rng.uniform(0, 6)))
        out.append(Frame(np.zeros((24, 32), np.float32), view, T_carm_transducer=T))
    return out


class _Offset:
    """The true angles plus a fixed error (rad); azimuth wrapped, as a real source returns it."""

    def __init__(self, d_az, d_el):
        self.d_az, self.d_el = d_az, d_el

    def estimate(self, frame, rng=None):
        az, el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        return float(wrap_angle(az + self.d_az)), el + self.d_el


def test_fixed_offsets_give_those_errors_and_a_unit_slope():
    frames = _frames()
    res = study.evaluate_orientation(_Offset(np.radians(2.0), np.radians(-1.0)), frames)
    assert len(res) == 12
    np.testing.assert_allclose(res["azimuth_error_deg"], 2.0, atol=1e-9)  # wrapped even across +-180
    np.testing.assert_allclose(res["elevation_error_deg"], -1.0, atol=1e-9)
    t = study.angle_table(res).set_index("angle")
    assert t.loc["azimuth", "mae_deg"] == pytest.approx(2.0) and t.loc["azimuth", "sd_deg"] == pytest.approx(0, abs=1e-9)
    assert t.loc["azimuth", "slope"] == pytest.approx(1.0) and t.loc["azimuth", "intercept_deg"] == pytest.approx(2.0)
    assert t.loc["elevation", "intercept_deg"] == pytest.approx(-1.0) and t.loc["elevation", "r2"] == pytest.approx(1.0)
    assert t.loc["elevation", "pearson_percent"] == pytest.approx(100.0)


def test_direction_error_and_the_misread_fraction():
    frames = _frames()
    res = study.evaluate_orientation(_Offset(0.0, np.radians(-1.0)), frames)
    np.testing.assert_allclose(res["direction_error_deg"], 1.0, atol=1e-6)
    # Every other frame misread: azimuth half a turn off at elevation >= 30 deg is >= 60 deg off.
    flips = [None] * len(frames)

    class _HalfMisread:
        def estimate(self, frame, rng=None):
            az, el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
            i = frames.index(frame)
            flips[i] = i % 2 == 1
            return (float(wrap_angle(az + np.pi)), max(el, np.radians(30))) if flips[i] else (az, el)

    s = study.direction_error_summary(study.evaluate_orientation(_HalfMisread(), frames), misread_deg=30.0)
    assert s["n"] == 12 and s["misread_fraction"] == pytest.approx(0.5)
    assert s["median_deg"] >= 0 and s["p90_deg"] >= 59.9
    with pytest.raises(ValueError, match="misread_deg must be finite and > 0"):
        study.direction_error_summary(res, misread_deg=0)


def test_scatter_figure_has_both_angles():
    res = study.evaluate_orientation(_Offset(0.05, 0.02), _frames(6, seed=1))
    fig = study.scatter_figure(res)
    assert [ax.get_xlabel() for ax in fig.axes] == ["reference azimuth (deg)", "reference elevation (deg)"]
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_frames_without_truth_are_rejected():
    view = View.from_gantry(0.0, shape=(24, 32))
    with pytest.raises(ValueError, match="no true pose"):
        study.evaluate_orientation(_Offset(0, 0), [Frame(np.zeros((24, 32), np.float32), view)])


class _Pair:
    """A source with its own two candidates: the truth turned by a known angle, and a decoy."""

    def __init__(self, angle_deg, fell_back=False):
        self.angle, self.fell_back = np.radians(angle_deg), fell_back

    def candidates(self, frame, rng=None):
        d = beam_direction_of_pose(frame.T_carm_transducer)
        axis = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
        axis /= np.linalg.norm(axis)
        turned = d * np.cos(self.angle) + np.cross(axis, d) * np.sin(self.angle)  # Rodrigues, axis ⟂ d
        return np.stack([-d, turned]), self.fell_back


def test_candidate_errors_take_the_nearer_candidate_and_agree_with_the_direction_error():
    frames = _frames()
    offset = _Offset(0.0, np.radians(-1.0))
    per_frame = study.candidate_errors({"pair": _Pair(2.5), "offset": offset}, frames)
    assert len(per_frame) == 2 * len(frames)
    pair = per_frame[per_frame.source == "pair"]
    np.testing.assert_allclose(pair["candidate_error_deg"], 2.5, atol=1e-9)
    # an (azimuth, elevation) source: eq. 4's pair, whose nearer candidate is the direction error
    direction = study.evaluate_orientation(offset, frames)["direction_error_deg"].to_numpy()
    np.testing.assert_allclose(per_frame[per_frame.source == "offset"]["candidate_error_deg"], direction, atol=1e-6)
    summary = study.candidate_error_summary(per_frame).set_index("source")
    assert summary.loc["pair", "median_deg"] == pytest.approx(2.5) and summary.loc["pair", "fallback_fraction"] == 0
    assert summary.loc["offset", "elevation_mae_deg"] == pytest.approx(1.0, abs=1e-6)
    fell = study.candidate_errors({"f": _Pair(40.0, fell_back=True)}, frames[:3])
    s = study.candidate_error_summary(fell).iloc[0]
    assert s["fallback_fraction"] == 1.0 and s["misread_fraction"] == 1.0
    with pytest.raises(ValueError, match="sources"):
        study.candidate_errors({}, frames)
