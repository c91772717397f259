"""histostudy.study.orientation (notebook 03): per-frame angles against the true pose, the §III statistics,
the figure, the initialiser comparison, the notebook's parameters checked by name, and what each part writes into a
section through ``record``."""

import numpy as np
import pytest

from histostudy.imaging import Frame, View
from histostudy.learning import (
    LearnedOrientation,
    OracleSegmenter,
    angles_from_direction,
    beam_direction_of_pose,
    wrap_angle,
)
from histostudy.pose import ConicOrientation
from histostudy.reporting import SectionWriter
from histostudy.study import orientation as study
from histostudy.study.orientation import _section
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
    t = _section.angle_table(res).set_index("angle")
    assert t.loc["azimuth", "mae_deg"] == pytest.approx(2.0)
    assert t.loc["azimuth", "sd_deg"] == pytest.approx(0, abs=1e-9)
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
    per_frame = study.candidate_errors({"pair": _Pair(2.5), "offset": offset}, frames, 0)
    assert len(per_frame) == 2 * len(frames)
    pair = per_frame[per_frame.source == "pair"]
    np.testing.assert_allclose(pair["candidate_error_deg"], 2.5, atol=1e-9)
    # an (azimuth, elevation) source: eq. 4's pair, whose nearer candidate is the direction error
    direction = study.evaluate_orientation(offset, frames)["direction_error_deg"].to_numpy()
    np.testing.assert_allclose(per_frame[per_frame.source == "offset"]["candidate_error_deg"], direction, atol=1e-6)
    summary = study.candidate_error_summary(per_frame).set_index("source")
    assert summary.loc["pair", "median_deg"] == pytest.approx(2.5) and summary.loc["pair", "fallback_fraction"] == 0
    assert summary.loc["offset", "elevation_mae_deg"] == pytest.approx(1.0, abs=1e-6)
    fell = study.candidate_errors({"f": _Pair(40.0, fell_back=True)}, frames[:3], 0)
    s = study.candidate_error_summary(fell).iloc[0]
    assert s["fallback_fraction"] == 1.0 and s["misread_fraction"] == 1.0
    with pytest.raises(ValueError, match="sources"):
        study.candidate_errors({}, frames, 0)
    with pytest.raises(TypeError, match="rng"):
        study.candidate_errors({"pair": _Pair(2.5)}, frames, None)


class _Frames:
    """The ``frame(i)`` interface of HybridFrames over a list."""

    def __init__(self, frames):
        self.frames = frames

    def frame(self, i):
        return self.frames[i]


class _Noisy:
    """The true angles plus Gaussian noise drawn from the rng it is given."""

    def estimate(self, frame, rng):
        az, el = angles_from_direction(beam_direction_of_pose(frame.T_carm_transducer), frame.view)
        return float(wrap_angle(az + rng.normal(0, 0.1))), el + rng.normal(0, 0.1)


def _writer(tmp_path):
    return SectionWriter(tmp_path, study.SECTION, study.TITLE, profile="test", seed=0)


def test_candidate_errors_draw_from_the_given_seed_or_generator():
    frames = _frames(4)
    by_seed = study.candidate_errors({"noisy": _Noisy()}, frames, 3)
    by_generator = study.candidate_errors({"noisy": _Noisy()}, frames, np.random.default_rng(3))
    np.testing.assert_array_equal(by_seed["candidate_error_deg"], by_generator["candidate_error_deg"])
    other = study.candidate_errors({"noisy": _Noisy()}, frames, 4)
    assert not np.allclose(other["candidate_error_deg"], by_seed["candidate_error_deg"])


def test_load_vgg19_finds_the_shipped_weights(monkeypatch):
    source, path = study.load_vgg19()
    assert isinstance(source, LearnedOrientation) and path.name == "vgg19_standard.safetensors"
    monkeypatch.setattr("histostudy.study.held_out.shipped_model", lambda name: None)
    with pytest.raises(FileNotFoundError,
                       match=r"VGG19 .*\(vgg19_standard\.safetensors .*histostudy train orientation"):
        study.load_vgg19()


def test_evaluation_statistics_and_direction_error(tmp_path):
    writer = _writer(tmp_path)
    evaluation = study.evaluation_section(_Offset(np.radians(2.0), np.radians(-1.0)), _Frames(_frames()), 10,
                                          timer=writer.timer)
    study.record(writer, evaluation)
    results = evaluation.results
    assert len(results) == 10 and "render and regress 10 frames" in writer.timings_s
    assert writer.values["regression_seconds_median"] == pytest.approx(results["seconds"].median())
    part = study.angle_statistics_part(results)
    study.record(writer, part)
    table = part.table("angle_statistics")
    assert list(table["angle"]) == ["azimuth", "elevation"]
    ours = {row["key"]: row for row in writer.comparisons}
    assert len(ours) == 10
    assert (ours["angles.azimuth.mae"]["ours"], ours["angles.azimuth.mae"]["ours_sd"]) == pytest.approx((2.0, 0.0))
    assert ours["angles.elevation.intercept"]["ours"] == pytest.approx(-1.0)
    part = study.direction_error_part(results)
    study.record(writer, part)
    direction = part.values["direction_error"]
    assert writer.values["direction_error"] is direction and direction["n"] == 10
    row = writer.comparisons[-1]
    assert row["key"] == "angles.direction.mae" and row["paper_key"] is None
    assert row["note"].endswith("0 % of frames off by > 30°")


def test_orientation_initialisers_and_their_keys():
    vgg = _Offset(0.0, 0.0)
    both = study.orientation_initialisers(vgg, unet=OracleSegmenter())
    assert list(both) == ["VGG19 (§II-B.4)", "conic, U-Net labels", "conic, reference labels"]
    assert both["VGG19 (§II-B.4)"] is vgg
    assert all(isinstance(c, ConicOrientation) and c.fallback is vgg for c in list(both.values())[1:])
    assert list(study.orientation_initialisers(vgg)) == ["VGG19 (§II-B.4)", "conic, reference labels"]
    assert [_section.initialiser_key(name) for name in both] == ["vgg19", "conic_U-Net", "conic_reference"]


def test_initialiser_comparison_section(tmp_path):
    writer = _writer(tmp_path)
    frames = _frames(4)
    comparison = study.initialiser_comparison_section({"pair": _Pair(2.5), "VGG19 (stand-in)": _Pair(40.0, True)},
                                                      frames, rng=study.INITIALISER_RNG_SEED, timer=writer.timer)
    study.record(writer, comparison)
    summary = comparison.summary
    assert list(summary["source"]) == ["pair", "VGG19 (stand-in)"]
    assert "candidate directions of 2 initialisers on 4 frames" in writer.timings_s
    assert [t.name for t in writer.tables] == ["initialiser_candidates", "initialiser_summary"]
    first, second = writer.comparisons
    assert first["key"] == "initialiser.pair.direction" and first["ours"] == pytest.approx(2.5)
    assert second["key"] == "initialiser.vgg19.direction" and second["note"].endswith("100 % fell back to the VGG19")


def test_stand_ins_part_names_the_manifest(tmp_path):
    class Net:
        manifest = {"config": {"arch": "vgg19"}, "training_steps": 80}

    writer = _writer(tmp_path)
    study.record(writer, study.stand_ins_part(Net(), tmp_path / "vgg19.safetensors", 7))
    assert writer.stand_ins[0]["synthetic"] == "7 held-out synthetic hybrid frames with the true pose as the reference"
    assert writer.stand_ins[1]["synthetic"].endswith("80 training steps (manifest vgg19.json)")
    assert writer.paragraphs[0].startswith("Azimuth errors are wrapped")


# --- the notebook's parameters and set-up -----------------------------------------------------------

#: The parameters cell of notebooks/03_orientation.ipynb as stored (its defaults).
DEFAULTS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu",
                render_spacing_mm=0.125, background="mixed", n_eval_images=3, weights="", cache_frames=True,
                render_workers=1,
                geometric_initialiser=True)


def test_the_parameters_are_the_notebooks_with_the_geometric_initialiser(notebook_parameters):
    params = study.OrientationConfig.from_parameters(notebook_parameters("03_orientation"))
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS
    assert list(params.recorded()) == list(study.OrientationConfig.RECORDED) == list(DEFAULTS)[:8]


def test_prepare_loads_the_shipped_vgg19_and_the_frames():
    setup = study.prepare({**DEFAULTS, "cache_frames": False}, 7)
    assert isinstance(setup.params, study.OrientationConfig) and setup.seed == 7
    assert isinstance(setup.source, LearnedOrientation) and setup.weights_path.name == "vgg19_standard.safetensors"
    assert setup.frames.split == "eval" and setup.frames.seed == 7
