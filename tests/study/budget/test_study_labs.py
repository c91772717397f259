"""Many labs: lab 0 is the single lab, every lab has its own draws from its own seed, frames and
segmentations shared across labs are the ones each lab would have made, and the labs' records do
not depend on the chunks or the workers."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane, random_background, render_frame, shared_frames
from histostudy.study.budget._labs import draw_labs, frames_alike, lab_magnitudes, lab_seed, labs_records, run_labs
from histostudy.study.budget._run import BudgetSetup, run_error_budget
from histostudy.study.budget._sources import LAB_SOURCES, LabErrorModel, draw_lab
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.study.targeting.setup import TargetingStudyConfig
from histostudy.transducer import TransducerModel


@pytest.fixture(scope="module")
def models():
    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    return model, physical


def _model(*sources):
    default = LabErrorModel()
    return dataclasses.replace(default.off(), **{s: getattr(default, s) for s in sources})


def test_lab_zero_is_the_single_lab_and_the_others_draw_their_own(models):
    _, physical = models
    model = _model("manufacturing", "bubble_offset", "projection", "gantry_sag")
    seed, physical_seed = np.random.SeedSequence(11).spawn(2)
    labs = draw_labs(model, seed, 4, physical=physical, views=default_biplane(), physical_seed=physical_seed)
    single = draw_lab(model, seed, physical=physical, views=default_biplane(), physical_seed=physical_seed)
    assert np.array_equal(labs[0].bubble_offset_mm, single.bubble_offset_mm)
    assert np.array_equal(labs[0].physical.focal_point_mm, single.physical.focal_point_mm)
    assert all(np.array_equal(a.P, b.P) for a, b in zip(labs[0].estimator_views, single.estimator_views))
    offsets = np.array([lab.bubble_offset_mm for lab in labs])
    assert len({tuple(o) for o in offsets}) == 4  # every lab its own offset
    focal = np.array([lab.physical.focal_point_mm for lab in labs])
    assert len({tuple(f) for f in focal}) == 4  # and its own transducer
    again = draw_labs(model, seed, 4, physical=physical, views=default_biplane(), physical_seed=physical_seed)
    assert np.array_equal(offsets, [lab.bubble_offset_mm for lab in again])
    assert lab_seed(seed, 0) is seed
    # a lab's seed lies apart from every stream lab 0 draws from (a source, or a source and an experiment)
    keys = {tuple(lab_seed(seed, k).spawn_key) for k in range(1, 4)}
    assert not keys & {(*seed.spawn_key, i, e) for i in range(len(LAB_SOURCES)) for e in range(20_000)}
    with pytest.raises(ValueError, match="n_labs"):
        draw_labs(model, seed, 0, physical=physical, views=default_biplane())


def test_frames_alike_and_magnitudes(models):
    _, physical = models
    alike = draw_labs(_model("bubble_offset", "projection"), 5, 3, physical=physical, views=default_biplane())
    assert frames_alike(alike) and frames_alike(alike, "targeting")
    sag = draw_labs(_model("gantry_sag", "bubble_offset"), 5, 3, physical=physical, views=default_biplane())
    assert not frames_alike(sag)
    # labs drawn apart have their own arms; lab 0 with another magnitude of a source keeps its arm
    arms = draw_labs(_model("bubble_offset", "robot_accuracy"), 5, 2, physical=physical, views=default_biplane())
    assert frames_alike(arms) and not frames_alike(arms, "targeting")
    again = draw_lab(_model("robot_accuracy"), arms[0].seed, physical=physical, views=default_biplane())
    assert frames_alike([arms[0], dataclasses.replace(again, physical=arms[0].physical)], "targeting")
    sizes = lab_magnitudes(sag).set_index("lab")
    assert list(sizes.columns) == ["bubble_offset", "gantry_sag"]
    for k, lab in enumerate(sag):
        assert sizes.loc[k, "bubble_offset"] == pytest.approx(np.linalg.norm(lab.bubble_offset_mm))
        moved = [np.linalg.norm(f.source_mm - s.source_mm) for f, s in zip(lab.frame_views, lab.study_views)]
        assert sizes.loc[k, "gantry_sag"] == pytest.approx(np.mean(moved)) and sizes.loc[k, "gantry_sag"] > 0


def test_shared_frames_are_the_ones_each_call_makes(models):
    model, physical = models
    T = np.eye(4)
    T[:3, 3] = [0.0, -140.0, 0.0]
    view = default_biplane()[0]

    def render(seed):
        rng = np.random.default_rng(seed)
        scene = random_background(np.random.default_rng(1), "phantom")  # a new object, the same scene
        frame = render_frame(model, T, view, rng=rng, physical=physical, background=scene, n_splats=2)
        return frame, rng.random()

    plain, after = render(5)
    with shared_frames() as memo:
        first, after_first = render(5)
        second, after_second = render(5)
        other, _ = render(6)
    assert (memo.misses, memo.hits) == (2, 1)
    for frame in (first, second):
        assert np.array_equal(frame.image, plain.image) and np.array_equal(frame.labels, plain.labels)
    assert after == after_first == after_second  # the Generator left where rendering leaves it
    assert second.image is not first.image and not np.array_equal(other.image, plain.image)


@pytest.fixture(scope="module")
def tiny(models):
    model, physical = models
    # half-resolution views: the shared and the separate runs compare at any resolution, 4x fewer pixels
    labs = draw_labs(_model("bubble_offset", "projection", "registration"), 21, 2, physical=physical,
                     views=[v.scaled(0.5) for v in default_biplane()])
    pose_config = PoseStudyConfig(n_experiments=1, modes=("fast",), track=False, n_splats=2, background="phantom")
    targeting_config = TargetingStudyConfig(n_experiments=1, n_splats=2, background="none", bias_correction=False)
    setup = BudgetSetup(labs[0], pose_config, targeting_config, model, model)
    shared = run_labs(setup, labs, seed=5)
    return setup, labs, shared


@pytest.mark.slow
def test_a_lab_through_the_shared_path_is_the_lab_of_the_budget(tiny):
    setup, labs, shared = tiny
    assert shared.attrs["frames"][1] > 0 and shared.attrs["segmentations"][1] > 0  # lab 1 reused lab 0's
    plain = run_error_budget(dataclasses.replace(setup, lab=labs[1]), seed=5,
                             configurations=[("baseline", labs[1].model.off()), ("lab", labs[1].model)])
    expected = labs_records(plain).assign(lab=1)
    got = shared[shared["lab"] == 1].reset_index(drop=True)
    # exact: a shared frame is the frame the lab renders, with its Generator left alike (tolerance 0)
    pd.testing.assert_frame_equal(got[expected.columns].reset_index(drop=True), expected.reset_index(drop=True),
                                  check_exact=True, check_dtype=False)
    alone = run_labs(setup, labs[1:], seed=5, indices=[1], share=False)  # nothing shared, nothing memoised
    assert alone.attrs["frames"] == (0, 0)
    pd.testing.assert_frame_equal(alone, got[alone.columns], check_exact=True, check_dtype=False)
    assert set(shared["study"]) == {"pose", "targeting"} and list(shared["lab"].unique()) == [0, 1]


@pytest.mark.slow
def test_the_labs_records_depend_neither_on_chunks_nor_workers(tiny):
    setup, labs, shared = tiny
    chunked = run_labs(setup, labs, seed=5, studies=("pose",), labs_per_task=1, executor="local:2")
    assert chunked.attrs["frames"][1] == 0  # one lab per task: nothing to share
    expected = shared[shared["study"] == "pose"].reset_index(drop=True)
    assert expected.drop(columns=chunked.columns).isna().all().all()  # the targeting rows' columns
    expected = expected[chunked.columns]
    pd.testing.assert_frame_equal(chunked, expected, check_exact=True, check_dtype=False)
    indexed = run_labs(setup, labs[1:], seed=5, studies=("pose",), indices=[7])
    assert list(indexed["lab"]) == [7]
    lab1 = expected[expected["lab"] == 1].reset_index(drop=True)
    pd.testing.assert_frame_equal(indexed.drop(columns="lab"), lab1.drop(columns="lab"), check_exact=True,
                                  check_dtype=False)


@pytest.mark.slow
def test_a_centre_only_run_is_the_full_run_s_centre(tiny):
    setup, labs, shared = tiny
    centres = run_labs(setup, labs, seed=5, studies=("pose",), centre_only=True)
    full = shared[shared["study"] == "pose"].reset_index(drop=True)
    # the centre's columns are the whole run's, to the bit; the margins' are not made
    centre_columns = [c for c in centres.columns if c not in ("n_failed", "failure")]
    assert {"centre_err_euclidean", "centre_err_depth"} <= set(centre_columns)
    assert not {"margin_err_overall", "radius_err_overall", "precision"} & set(centres.columns)
    pd.testing.assert_frame_equal(centres[centre_columns], full[centre_columns], check_exact=True, check_dtype=False)
    assert centres.attrs["frames"][0] < shared.attrs["frames"][0]  # fewer frames rendered
    with pytest.raises(ValueError, match="centre_only must be True or False, got 1"):
        run_labs(setup, labs, seed=5, centre_only=1)
