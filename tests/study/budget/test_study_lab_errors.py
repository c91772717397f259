"""The lab error model: its sources, switches and draws (each source on its own stream)."""

import dataclasses

import numpy as np
import pytest

from histostudy.imaging import default_biplane
from histostudy.study import LabErrorModel
from histostudy.study.budget._sources import (
    LAB_SOURCES,
    BubbleOffset,
    GantrySag,
    ProjectionError,
    RegistrationError,
    draw_lab,
)
from histostudy.transducer import ManufacturingDeviation, TransducerModel, TransducerSpec


@pytest.fixture(scope="module")
def physical():
    return TransducerModel.build_physical(TransducerSpec(), 0.94, rng=np.random.default_rng(np.random.SeedSequence(4)))


@pytest.fixture(scope="module")
def views():
    return default_biplane()


def test_switches_keep_the_other_sources():
    model = LabErrorModel()
    assert model.enabled == LAB_SOURCES
    assert model.off().enabled == ()
    assert model.only("registration").enabled == ("registration",)
    assert model.only("registration").registration == model.registration
    assert model.without("annotation").enabled == tuple(s for s in LAB_SOURCES if s != "annotation")
    with pytest.raises(ValueError, match="source must be one of"):
        model.only("sag")
    with pytest.raises(TypeError, match="LabErrorModel.projection"):
        LabErrorModel(projection=0.5)
    with pytest.raises(ValueError, match="GantrySag.sd_mm"):
        GantrySag(sd_mm=-1.0)
    with pytest.raises(ValueError, match="BubbleOffset.sd_mm"):
        BubbleOffset(sd_mm=(1.0, 2.0))
    assert [row["source"] for row in model.describe()] == list(LAB_SOURCES)


def test_the_same_seed_gives_the_same_lab_and_toggling_one_source_moves_no_other(physical, views):
    model = LabErrorModel(manufacturing=None)
    a = draw_lab(model, 7, physical=physical, views=views)
    b = draw_lab(model, 7, physical=physical, views=views)
    assert np.array_equal(a.bubble_offset_mm, b.bubble_offset_mm)
    assert all(np.array_equal(u.P, v.P) for u, v in zip(a.estimator_views, b.estimator_views))
    for name in ("bubble_offset", "projection", "gantry_sag"):
        alone = draw_lab(model.only(name), 7, physical=physical, views=views)
        variant = a.variant(model.only(name))
        assert np.array_equal(alone.bubble_offset_mm, variant.bubble_offset_mm)
        for u, v in zip(alone.estimator_views + alone.frame_views, variant.estimator_views + variant.frame_views):
            assert np.array_equal(u.P, v.P)
    only_bubble = a.variant(model.only("bubble_offset"))
    assert np.array_equal(only_bubble.bubble_offset_mm, a.bubble_offset_mm)
    assert only_bubble.frame_views == tuple(views) and only_bubble.estimator_views == tuple(views)
    for e in range(3):
        full, alone = a.experiment(e), draw_lab(model.only("registration"), 7, physical=physical,
                                                views=views).experiment(e)
        assert np.array_equal(full.T_cbct_carm, alone.T_cbct_carm)
    with pytest.raises(ValueError, match="not this lab's"):
        a.variant(dataclasses.replace(model, gantry_sag=GantrySag(sd_mm=2.0)))


def test_draws_have_the_stated_spread(physical, views):
    model = LabErrorModel(manufacturing=None, projection=ProjectionError(reprojection_px=0.5, source_mm=0.0),
                          gantry_sag=None)
    offsets, shifts, translations = [], [], []
    pts = np.zeros((1, 3))
    for seed in range(300):
        lab = draw_lab(model, seed, physical=physical, views=views)
        offsets.append(lab.bubble_offset_mm)
        shifts.append(lab.estimator_views[0].project(pts)[0] - views[0].project(pts)[0])
        translations.append(lab.experiment(0).T_cbct_carm[:3, 3])
    assert np.allclose(np.std(offsets, axis=0), model.bubble_offset.sd_mm, rtol=0.15)
    assert np.allclose(np.std(shifts, axis=0), 0.5, rtol=0.15)
    assert np.allclose(np.std(translations, axis=0), model.registration.translation_mm, rtol=0.15)


def test_the_reading_of_a_cbct_point(physical, views):
    point = np.array([3.0, -2.0, 10.0])
    base = LabErrorModel().off()
    for name, field in (("annotation", "annotation_centroid_mm"), ("phantom_motion", "phantom_motion_mm")):
        lab = draw_lab(dataclasses.replace(base, **{name: getattr(LabErrorModel(), name)}), 3, physical=physical,
                       views=views)
        draw = lab.experiment(0)
        assert np.allclose(draw.measured_point(point) - point, getattr(draw, field))
        assert np.allclose(draw.read_target(point), point)
    lab = draw_lab(dataclasses.replace(base, registration=RegistrationError(translation_mm=0.3, rotation_deg=0.1)), 3,
                   physical=physical, views=views)
    T = lab.experiment(0).T_cbct_carm
    assert np.allclose(lab.experiment(0).read_target(point), T[:3, :3] @ point + T[:3, 3])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3))
    off = draw_lab(base, 3, physical=physical, views=views).experiment(0)
    assert np.array_equal(off.measured_point(point), point) and np.array_equal(off.T_cbct_carm, np.eye(4))


def test_the_labs_transducer_moves_the_studys_quadrants_by_its_tolerances():
    seq = np.random.SeedSequence(11)
    study = TransducerModel.build_physical(TransducerSpec(), 0.94, rng=np.random.default_rng(seq))
    tolerances = ManufacturingDeviation(quadrant_offset_sd_mm=0.4, quadrant_tilt_sd_deg=0.15)
    model = LabErrorModel(manufacturing=tolerances).only("manufacturing")
    lab = draw_lab(model, 1, physical=study, views=default_biplane(), physical_seed=seq)
    # the same standard-normal draws, scaled from the study's 0.2 mm offsets to 0.4 mm
    study_offsets = study.quadrant_transforms[:, :3, 3]
    lab_offsets = lab.physical.quadrant_transforms[:, :3, 3]
    assert np.allclose(lab.physical.quadrant_transforms[:, :3, :3], study.quadrant_transforms[:, :3, :3], atol=1e-12)
    assert lab.study_physical is study
    assert not np.allclose(lab_offsets, study_offsets)
    off = draw_lab(model.off(), 1, physical=study, views=default_biplane(), physical_seed=seq)
    assert off.physical is study
