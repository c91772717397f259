"""histostudy.study.projections (notebook 01): geometry measured on the points, counts, label fractions, the
biplane pair, the notebook's parameters checked by name, and what each ``*_part`` writes into a
section through ``record``."""

import contextlib
import json

import numpy as np
import pytest

from histostudy.geometry import check_rigid
from histostudy.imaging import Frame, default_biplane, render_labels
from histostudy.reporting import SectionWriter
from histostudy.study import projections as study
from histostudy.study.projections import _section
from histostudy.transducer import TransducerModel, TransducerSpec, pose_facing


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(TransducerSpec(), spacing_mm=0.47)


@pytest.fixture(scope="module")
def models():
    return _section.build_models(1.0, 0.47, rng=_section.stage_generators(5).physical)


@pytest.fixture(scope="module")
def pair(models):
    rngs = _section.stage_generators(5)
    return study.render_biplane_pair(models, "phantom", rng_background=rngs.background, rng_render=rngs.render,
                                     n_splats=1, photons_per_pixel=None)


def _writer(tmp_path):
    return SectionWriter(tmp_path, study.SECTION, study.TITLE, profile="test", seed=5)


def _comparisons(writer):
    return {row["label"]: row["ours"] for row in writer.comparisons}


def test_geometry_is_measured_from_the_points(model):
    geo = _section.model_geometry(model)
    assert geo["sphere_radius_mm"] == pytest.approx(138.7, abs=1e-6)
    assert np.allclose(geo["sphere_centre_mm"], 0, atol=1e-6)
    assert geo["aperture_x_mm"] == pytest.approx(240.0, abs=2 * 0.47)
    assert geo["aperture_y_mm"] == pytest.approx(170.0, abs=2 * 0.47)
    assert geo["cutout_diameter_mm"] == pytest.approx(64.0, abs=2 * 0.47)
    # a different spec gives different measurements: nothing is copied from the defaults
    other = _section.model_geometry(
        TransducerModel.build(TransducerSpec(radius_mm=150.0, cutout_diameter_mm=50.0), 0.47))
    assert other["sphere_radius_mm"] == pytest.approx(150.0, abs=1e-6)
    assert other["cutout_diameter_mm"] == pytest.approx(50.0, abs=2 * 0.47)


def test_point_count_table(model):
    table = _section.point_count_table({"a": model})
    assert table.iloc[-1]["a"] == sum(len(p) for p in model.points.values())
    assert list(table["feature class"][:5]) == ["transducer", "outer_boundary", "inner_boundary", "gaps", "screws"]


def test_label_fraction_table_sums_to_the_image(model):
    view = default_biplane()[1]
    labels = render_labels(model, pose_facing(), view)
    table = _section.label_fraction_table([Frame(np.zeros(view.shape, np.float32), view, labels=labels)])
    assert table["pixels"].sum() == labels.size and table["percent"].sum() == pytest.approx(100.0)


def test_render_timing_reports_every_stage(model):
    view = default_biplane()[0].scaled(0.25)
    table = _section.render_timing(model, pose_facing(), view, background=np.zeros(view.shape), rng=0, repeats=2,
                                n_splats=2)
    assert list(table["stage"]) == ["background projection", "transducer splatting", "frame, background precomputed"]
    assert (table["median_s"] > 0).all() and (table["repeats"] == 2).all()
    with pytest.raises(ValueError, match="repeats"):
        _section.render_timing(model, pose_facing(), view, background=None, rng=0, repeats=0)
    with pytest.raises(TypeError, match="rng"):
        _section.render_timing(model, pose_facing(), view, background=None, rng=None)


def test_stage_generators_are_seeded_and_independent():
    a, b = _section.stage_generators(7), _section.stage_generators(7)
    first = [g.random() for g in a]
    assert first == [g.random() for g in b]
    assert len(set(first)) == 4  # four distinct streams
    expected = np.random.default_rng(np.random.SeedSequence(7).spawn(4)[2]).random()
    assert _section.stage_generators(7).render.random() == expected


def test_build_models_spacings_and_timer(models):
    assert (models.pose.spacing_mm, models.render.spacing_mm, models.physical.spacing_mm) == (1.0, 0.47, 0.47)
    # the physical transducer deviates from the digital one; the digital focal point is the origin
    assert 0 < np.linalg.norm(models.physical.focal_point_mm) < 5.0
    assert np.allclose(models.render.focal_point_mm, 0.0)
    timed = []

    def timer(name):
        timed.append(name)
        return contextlib.nullcontext()

    again = _section.build_models(1.0, 0.47, rng=_section.stage_generators(5).physical, timer=timer)
    assert timed == ["build digital model 1.0 mm", "build digital model 0.47 mm", "build physical model 0.47 mm"]
    np.testing.assert_array_equal(again.physical.focal_point_mm, models.physical.focal_point_mm)


def test_example_pose_puts_the_focal_point_near_the_isocentre():
    T = _section.example_pose()
    check_rigid(T)
    np.testing.assert_allclose(T[:3, 3], [4.0, -6.0, 8.0])
    # the transducer's -z (centre to focal point) along the normalised requested direction
    direction = np.array([0.15, 1.0, 0.25]) / np.linalg.norm([0.15, 1.0, 0.25])
    np.testing.assert_allclose(-T[:3, 2], direction, atol=1e-12)


def test_render_biplane_pair_is_seeded_and_labelled(models, pair):
    assert [v.name for v in pair.views] == ["A", "B"] and len(pair.frames) == 2
    np.testing.assert_array_equal(pair.T_carm_transducer, _section.example_pose())
    for frame in pair.frames:
        assert frame.labels.shape == frame.image.shape and set(np.unique(frame.labels)) == set(range(6))
    rngs = _section.stage_generators(5)
    again = study.render_biplane_pair(models, "phantom", rng_background=rngs.background, rng_render=rngs.render,
                                      n_splats=1, photons_per_pixel=None)
    np.testing.assert_array_equal(again.frames[1].image, pair.frames[1].image)


def test_view_geometry_table_projects_the_focal_point(pair):
    table = _section.view_geometry_table(pair.frames, pair.T_carm_transducer)
    assert list(table["view"]) == ["A", "B"] and list(table["primary_deg"]) == [-45.0, 45.0]
    for i, frame in enumerate(pair.frames):
        u, v = frame.view.project(pair.T_carm_transducer[:3, 3])[0]
        assert (table.loc[i, "focal point u (px)"], table.loc[i, "focal point v (px)"]) == (u, v)
    rows, cols = pair.frames[0].view.shape
    assert table["network input (0.25x)"][0] == f"{round(cols / 4)}x{round(rows / 4)}"
    # a focal point at the isocentre projects to the middle of the detector
    centred = _section.view_geometry_table(pair.frames, np.eye(4))
    assert np.allclose(centred["focal point u (px)"], (cols - 1) / 2, atol=2) and np.allclose(
        centred["focal point v (px)"], (rows - 1) / 2, atol=2)


def test_point_counts_and_geometry_parts(tmp_path, models):
    writer = _writer(tmp_path)
    part = study.point_counts_part(models)
    study.record(writer, part)
    counts = part.table("point_counts")
    assert list(counts.columns) == ["feature class", "1.0 mm (pose)", "0.47 mm (render)", "0.47 mm physical"]
    assert (tmp_path / "tables" / "point_counts.csv").is_file()
    part = study.model_geometry_part(models)
    study.record(writer, part)
    geometry = part.values["model_geometry"]
    assert writer.values["model_geometry"] is geometry
    ours = _comparisons(writer)
    assert ours["Cap sphere radius (least-squares fit of element points)"] == pytest.approx(138.7, abs=1e-6)
    assert ours["Grid spacing, pose-estimation model"] == 1.0 and ours["Feature classes with points"] == 5
    assert ours["Aperture, LR x TB (measured)"] == (f"{geometry['aperture_x_mm']:.1f} x "
                                                    f"{geometry['aperture_y_mm']:.1f} mm")
    assert writer.values["physical_focal_point_shift_mm"] == pytest.approx(
        np.linalg.norm(models.physical.focal_point_mm))
    assert writer.values["spec"] == models.spec.to_dict()


def test_label_content_timing_and_stand_ins_parts(tmp_path, models, pair):
    writer = _writer(tmp_path)
    labels = study.label_content_part(pair)
    study.record(writer, labels)
    percent = study.label_percentages(labels.table("label_pixels"))
    assert list(percent.columns) == ["A", "B"] and np.allclose(percent.sum(), 100.0)
    ours = _comparisons(writer)
    assert ours["Feature classes visible in each view"] == 5
    assert ours["Gantry angles (plane A, plane B)"] == "-45°, +45° around PA"
    assert ours["Network input size (detector x 0.25)"] == "310x240"
    part = study.render_timing_part(models, pair, repeats=1, rng=0, n_splats=1, splat_sigma_mm=0.5,
                                    photons_per_pixel=None)
    study.record(writer, part)
    timing = part.table("render_timing")
    assert timing["points"].iloc[1] == sum(models.physical.n_points.values())
    assert _comparisons(writer)["Splats per point"] == 1
    study.record(writer, study.stand_ins_part(models, background="phantom", photons_per_pixel=5e4, n_splats=1))
    assert len(writer.stand_ins) == 3 and "onto a 'phantom' background at 50000 photons" in writer.paragraphs[-1]
    saved = json.loads(writer.save().read_text())
    assert [t["name"] for t in saved["tables"]] == ["label_pixels", "views", "render_timing"]


# --- the notebook's parameters and set-up -----------------------------------------------------------

#: The parameters cell of notebooks/01_transducer_and_projections.ipynb as stored (its defaults).
DEFAULTS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu", pose_spacing_mm=0.47,
                render_spacing_mm=0.125, background="abdomen", timing_repeats=1, render_3d=True)


def test_the_parameters_are_the_notebooks_and_the_report_records_the_same_ones(notebook_parameters):
    cell = notebook_parameters("01_transducer_and_projections")
    params = study.TransducerProjectionsConfig.from_parameters(cell)
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS
    assert set(cell) - set(DEFAULTS) == {"profile", "seed", "output_dir"}
    assert list(params.recorded()) == list(_section.RECORDED_PARAMETERS) == [k for k in DEFAULTS if k != "render_3d"]
    assert params.render() == {"photons_per_pixel": 50000.0, "n_splats": 16, "splat_sigma_mm": 0.5, "device": "cpu"}
    with pytest.raises(AttributeError):
        params.n_splats = 2  # frozen


def test_prepare_builds_the_models_from_the_seeds_physical_generator(recording_timer):
    timer, timed = recording_timer()

    setup = study.prepare({**DEFAULTS, "pose_spacing_mm": 1.0, "render_spacing_mm": 0.47}, 5, timer=timer)
    assert isinstance(setup.params, study.TransducerProjectionsConfig) and setup.seed == 5
    assert setup.models.pose.spacing_mm == 1.0 and setup.models.render.spacing_mm == 0.47
    expected = _section.build_models(1.0, 0.47, rng=_section.stage_generators(5).physical)
    assert np.array_equal(setup.models.physical.focal_point_mm, expected.physical.focal_point_mm)
    assert setup.rngs.render.random() == _section.stage_generators(5).render.random()
    assert timed == ["build digital model 1.0 mm", "build digital model 0.47 mm", "build physical model 0.47 mm"]
