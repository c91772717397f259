"""histostudy.study.segmentation (notebook 02): per-image metrics, Table I, the precision tests and their paragraph,
the shipped weights and held-out frames, the notebook's parameters checked by name, and what each part
writes into a section through ``record``."""

import contextlib

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from histostudy.imaging import Frame, View
from histostudy.learning import OracleSegmenter, SegmentationDegradation
from histostudy.reporting import SectionWriter
from histostudy.study import held_out
from histostudy.study import segmentation as study
from histostudy.study.segmentation import _section
from histostudy.transducer import FEATURE_CLASSES


def _frames(n=5, seed=0):
    """Synthetic label images with every class present: nested rectangles and thin stripes."""
    rng = np.random.default_rng(seed)
    view = View.from_gantry(0.0, shape=(48, 64))
    out = []
    for _ in range(n):
        lab = np.zeros((48, 64), np.uint8)
        r, c = rng.integers(2, 6, size=2)
        lab[r:40, c:58] = 1
        lab[r:r + 3, c:58] = 2
        lab[20:23, 10:50] = 3
        lab[r:40, 30:32] = 4
        lab[10:13, 12:15] = 5
        out.append(Frame(rng.normal(size=(48, 64)).astype(np.float32), view, labels=lab))
    return out


def test_perfect_segmentation_scores_100():
    per_class, per_image, preds = study.evaluate_segmentation(OracleSegmenter(), _frames(), keep=2)
    assert len(preds) == 2 and len(per_image) == 5
    assert np.allclose(per_image["global_accuracy"], 100) and np.allclose(per_image["weighted_iou"], 100)
    t = study.table1(per_class)
    assert list(t["class"]) == list(_section.CLASS_KEYS)
    assert np.allclose(t[["precision_mean", "recall_mean", "iou_mean", "accuracy_mean"]], 100)
    assert (t["images"] == 5).all()


def test_table1_and_tests_on_a_degraded_oracle_match_scipy():
    deg = SegmentationDegradation(recall={k: 0.7 for k in FEATURE_CLASSES},
                                  precision={k: 0.8 for k in FEATURE_CLASSES})
    frames = _frames(8, seed=1)
    per_class, per_image, _ = study.evaluate_segmentation(OracleSegmenter(deg), frames, np.random.default_rng(2))
    t = study.table1(per_class)
    gaps = per_class.loc[per_class["class"] == "gaps", "recall"]
    row = t[t["class"] == "gaps"].iloc[0]
    assert row["recall_mean"] == pytest.approx(gaps.mean()) and row["recall_sd"] == pytest.approx(gaps.std(ddof=1))
    assert 55 < row["recall_mean"] < 85  # about the requested 70 %
    anova, tukey, dropped = _section.precision_tests(per_class)
    groups = [per_class.loc[per_class["class"] == c, "precision"].dropna() for c in _section.CLASS_KEYS]
    ref = sps.f_oneway(*groups)
    assert dropped == [] and anova["F"] == pytest.approx(ref.statistic) and anova["p"] == pytest.approx(ref.pvalue)
    assert (anova["df_between"], anova["df_within"]) == (5, 6 * 8 - 6)
    assert len(tukey) == 15
    text = _section.anova_text(anova, tukey)
    assert text.startswith(f"A one-way ANOVA over the precision of the 6 classes gives F(5, 42) = {anova['F']:.1f}")
    overall = _section.summary(per_image)
    assert overall.loc[overall["metric"] == "global_accuracy", "mean"].iloc[0] == pytest.approx(
        per_image["global_accuracy"].mean())


def test_anova_text_names_the_lower_classes():
    tukey = pd.DataFrame({"group1": ["background", "background"], "group2": ["gaps", "screws"],
                          "meandiff": [-1.0, -8.9], "p_adj": [0.4, 1e-6], "lower": [-3.0, -10.1],
                          "upper": [1.0, -7.7], "reject": [False, True]})
    text = _section.anova_text({"F": 85.6, "df_between": 5, "df_within": 1262, "p": 1e-9}, tukey)
    assert "F(5, 1262) = 85.6, p < 1e-5" in text
    assert "screws (by 8.9 %" in text and "[7.7, 10.1]" in text and "gaps" not in text


def test_a_single_predicted_class_gives_no_tests():
    class Background:
        def segment(self, frame, rng=None):
            return np.zeros(frame.shape, np.uint8)

    per_class, _, _ = study.evaluate_segmentation(Background(), _frames(3))
    anova, tukey, dropped = _section.precision_tests(per_class)
    assert anova is None and tukey is None and set(dropped) == set(_section.CLASS_KEYS) - {"background"}
    with pytest.raises(ValueError, match="no reference labels"):
        study.evaluate_segmentation(Background(), [Frame(np.zeros((48, 64), np.float32), _frames(1)[0].view)])


class _Frames:
    """The ``frame(i)`` interface of HybridFrames over a list."""

    def __init__(self, frames):
        self.frames = frames

    def frame(self, i):
        return self.frames[i]


def _writer(tmp_path):
    return SectionWriter(tmp_path, study.SECTION, study.TITLE, profile="test", seed=0)


def test_resolve_weights_names_the_training_command(tmp_path):
    given = tmp_path / "net.safetensors"
    assert held_out.resolve_weights(str(given), "unet_standard", "U-Net", "segmentation") == given
    with pytest.raises(FileNotFoundError, match="no usable shipped VGG19 .*histostudy train orientation"):
        held_out.resolve_weights("", "no_such_network", "VGG19", "orientation")


def test_weights_part_and_its_summary_line(tmp_path):
    writer = _writer(tmp_path)
    manifest = {"sha256": "ab" * 32, "config": {"arch": "unet", "in_channels": 1, "n_classes": 6, "base_width": 8,
                                                 "depth": 4}, "profile": "standard", "training_steps": 1200,
                "training_minutes": 70.8, "device": "cpu"}
    study.record(writer, study.weights_part(tmp_path / "unet.safetensors", manifest))
    line = study.weights_summary("U-Net", tmp_path / "unet.safetensors", manifest, 0.25)
    assert line == ("U-Net (8...128 channels over 4 levels) from unet.safetensors: 1200 steps (profile standard), "
                    "input scale 0.25")
    table = pd.read_csv(tmp_path / "tables" / "network.csv", keep_default_na=False)
    assert dict(zip(table.iloc[:, 0], table["checkpoint"])) == {
        "network": "U-Net, 8...128 channels over 4 levels", "weights": "unet.safetensors", "SHA-256": "ab" * 6,
        "profile": "standard", "training steps": "1200", "training minutes": "71", "trained on": "cpu"}
    record = writer.values["weights"]
    assert record["manifest"] == str(tmp_path / "unet.json") and record["sha256"] == "ab" * 32
    assert record["validation"] is None


def test_held_out_frames_are_the_eval_split(tmp_path, monkeypatch):
    frames = held_out.held_out_frames(7, 2, render_spacing_mm=0.47, photons_per_pixel=1e4, n_splats=2,
                                   splat_sigma_mm=0.3, background="phantom", cache_frames=False)
    assert frames.split == "eval" and frames.cache_dir is None
    assert (frames.config.render_spacing_mm, frames.config.label_spacing_mm, frames.config.n_splats) == (0.47, 0.47, 2)
    monkeypatch.setenv("HISTOSTUDY_CACHE", str(tmp_path))
    timed = []
    cached = held_out.held_out_frames(7, 0, render_spacing_mm=0.47, photons_per_pixel=1e4, n_splats=2,
                                   splat_sigma_mm=0.3, background="phantom", render_workers=2,
                                   timer=lambda name: timed.append(name) or contextlib.nullcontext())
    assert cached.cache_dir is not None and timed == ["pre-render the uncached evaluation frames (2 processes)"]


def test_evaluation_and_table1_of_a_perfect_segmenter(tmp_path):
    writer = _writer(tmp_path)
    evaluation = study.evaluation_section(OracleSegmenter(), _Frames(_frames()), 4, keep=1, timer=writer.timer)
    study.record(writer, evaluation)
    per_class, per_image, predictions = evaluation.per_class, evaluation.per_image, evaluation.predictions
    assert len(per_image) == 4 and len(predictions) == 1 and "render and segment 4 frames" in writer.timings_s
    assert writer.values["segmentation_seconds_median"] == pytest.approx(per_image["seconds"].median())
    assert (tmp_path / "tables" / "per_image.csv").is_file()
    part = study.table1_part(per_class, per_image)
    study.record(writer, part)
    table = part.table("table1")
    assert list(table["class"]) == list(_section.CLASS_KEYS)
    by_key = {row["key"]: row for row in writer.comparisons}
    assert len(by_key) == 6 * 4 + 4 + 1
    assert by_key["table1.screws.recall"]["ours"] == pytest.approx(100.0)
    assert by_key["seg.global_accuracy"]["ours"] == pytest.approx(100.0) and by_key["seg.n_images"]["ours"] == 4


def test_background_minus_screws_ci_takes_the_papers_orientation():
    tukey = pd.DataFrame({"group1": ["background", "gaps"], "group2": ["screws", "screws"],
                          "lower": [-10.1, -3.0], "upper": [-7.7, 1.0]})
    assert _section.background_minus_screws_ci(tukey) == (7.7, 10.1)
    swapped = pd.DataFrame({"group1": ["screws"], "group2": ["background"], "lower": [7.7], "upper": [10.1]})
    assert _section.background_minus_screws_ci(swapped) == (7.7, 10.1)
    assert _section.background_minus_screws_ci(tukey.iloc[1:]) is None


def test_precision_tests_section_with_and_without_a_test(tmp_path):
    deg = SegmentationDegradation(recall={k: 0.7 for k in FEATURE_CLASSES},
                                  precision={k: 0.8 for k in FEATURE_CLASSES})
    per_class, _, _ = study.evaluate_segmentation(OracleSegmenter(deg), _frames(8, seed=1), np.random.default_rng(2))
    writer = _writer(tmp_path)
    tests = study.precision_tests_section(per_class)
    study.record(writer, tests)
    paragraph, tukey = tests.paragraph, tests.tukey
    assert len(tukey) == 15 and writer.paragraphs == [paragraph] and paragraph.startswith("A one-way ANOVA")
    keys = [row["key"] for row in writer.comparisons]
    assert keys[:4] == ["seg.anova_F", "seg.anova_df_between", "seg.anova_df_within", "seg.anova_p"]
    assert keys[-1] == "seg.tukey_screws_vs_background_ci"

    class Background:
        def segment(self, frame, rng=None):
            return np.zeros(frame.shape, np.uint8)

    per_class, _, _ = study.evaluate_segmentation(Background(), _frames(3))
    writer = _writer(tmp_path)
    tests = study.precision_tests_section(per_class)
    study.record(writer, tests)
    paragraph, tukey = tests.paragraph, tests.tukey
    assert tukey is None and paragraph.startswith("No ANOVA") and "screws" in paragraph
    assert writer.comparisons[0]["ours"] == "not computed" and writer.comparisons[0]["note"] == paragraph


def test_stand_ins_part_reports_the_detector_and_time(tmp_path):
    class Net:
        manifest = {"config": {"arch": "unet"}, "training_steps": 50}
        scale = 0.5

    writer = _writer(tmp_path)
    per_image = pd.DataFrame({"image": [0, 1, 2], "seconds": [0.1, 0.3, 0.2]})
    study.record(writer, study.stand_ins_part(Net(), tmp_path / "unet.safetensors", per_image,
                                              detector_shape=(960, 1240)))
    assert writer.stand_ins[0]["synthetic"].startswith("3 held-out synthetic hybrid frames")
    synthetic = writer.stand_ins[1]["synthetic"]
    assert "50 training steps" in synthetic and "(manifest unet.json)" in synthetic
    assert writer.paragraphs == ["Segmentation takes a median 0.20 s per full 1240x960 frame on this machine "
                                 "(downscaled by 0.5, logits upsampled to full size)."]


# --- the notebook's parameters and set-up -----------------------------------------------------------

#: The parameters cell of notebooks/02_segmentation.ipynb as stored (its defaults).
DEFAULTS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu",
                render_spacing_mm=0.125, background="mixed", n_eval_images=3, weights="", cache_frames=True,
                render_workers=1)


def test_the_parameters_are_the_notebooks_and_the_report_records_the_same_ones(notebook_parameters):
    cell = notebook_parameters("02_segmentation")
    params = study.SegmentationConfig.from_parameters(cell)
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS
    assert set(cell) - set(DEFAULTS) == {"profile", "seed", "output_dir"}
    assert list(params.recorded()) == list(study.SegmentationConfig.RECORDED) == list(DEFAULTS)[:8]
    with pytest.raises(AttributeError):
        params.n_eval_images = 2  # frozen


def test_missing_parameters_are_named_and_the_frames_are_the_held_out_ones():
    with pytest.raises(ValueError, match=r"parameters lack \['weights'\] \(notebook 02's"):
        study.SegmentationConfig.from_parameters({k: v for k, v in DEFAULTS.items() if k != "weights"})
    params = study.SegmentationConfig(**{**DEFAULTS, "cache_frames": False})
    frames = params.frames(7)
    assert frames.split == "eval" and frames.seed == 7 and frames.cache_dir is None
    assert frames.config == held_out.held_out_frames(7, 4, render_spacing_mm=0.125, photons_per_pixel=5e4, n_splats=16,
                                                  splat_sigma_mm=0.5, background="mixed", splat_device="cpu").config


def test_prepare_loads_the_shipped_unet_and_the_frames():
    setup = study.prepare({**DEFAULTS, "cache_frames": False}, 7)
    assert isinstance(setup.params, study.SegmentationConfig) and setup.seed == 7
    assert setup.weights_path.name == "unet_standard.safetensors" and setup.frames.split == "eval"
    assert setup.segmenter.manifest["sha256"]


def test_a_network_reads_in_words():
    from histostudy.study.held_out import network_description

    vgg = {"arch": "vgg19", "in_channels": 1, "n_classes": 36, "width": 0.125, "batch_norm": True,
           "angle_encoding": "cos_sin", "head": "regressor"}
    assert network_description(vgg) == "VGG19 at width 1/8, batch norms, (cos, sin) regressor"
    assert network_description(vgg, named=False) == "width 1/8, batch norms, (cos, sin) regressor"
    assert network_description({"arch": "vgg19", "head": "classifier"}) == "VGG19, classifier"
    assert network_description({"arch": "unet", "base_width": 4, "depth": 2, "input_stride": 2}) == \
        "U-Net, 4...16 channels over 2 levels, strided stem"
    assert network_description({"arch": "resnet", "depth": 18}) == "resnet, depth 18"
