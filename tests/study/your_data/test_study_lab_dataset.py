"""histostudy.study.your_data.lab_dataset: the generated lab-like dataset reads back through the lab's own
readers (DICOM XA geometry, NIfTI, STL, flange poses) and agrees with its synthetic truth."""

import json

import numpy as np
import pydicom
import pytest

from histostudy.imaging import View, default_biplane, load_frame, load_views, load_volume
from histostudy.lab import load_flange_poses
from histostudy.study.your_data.lab_dataset import write_lab_dataset
from histostudy.transducer import TransducerModel


def _small_views():
    return default_biplane(shape=(96, 124), pixel_mm=3.08)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    return write_lab_dataset(tmp_path_factory.mktemp("lab"), seed=9, n_cine_frames=3, views=_small_views())


def test_the_files_read_back_through_the_lab_readers_and_match_the_truth(lab):
    truth = json.loads(lab.truth.read_text())
    views = load_views(lab.views)
    points = np.random.default_rng(0).uniform(-40, 40, (10, 3))
    for (a, b) in lab.calibration_frames:
        for path, view in zip((a, b), views):
            again = View.from_dicom(path, name=view.name)
            np.testing.assert_allclose(again.project(points), view.project(points), atol=1e-6)
    # The flange poses, as transforms and as UR poses, and the chain the truth records.
    flanges = load_flange_poses(lab.flange_poses)
    data = json.loads(lab.flange_poses.read_text())
    np.testing.assert_allclose(load_flange_poses_from(data, "ur_pose"), flanges, atol=1e-9)
    Y, X = np.asarray(truth["T_carm_base"]), np.asarray(truth["T_flange_transducer"])
    np.testing.assert_allclose([Y @ F @ X for F in flanges], truth["station_T_carm_transducer"], atol=1e-9)
    # The cine: n frames per plane, FrameTime apart, each frame loadable by index.
    for path, view in zip(lab.cine, views):
        ds = pydicom.dcmread(path)
        assert int(ds.NumberOfFrames) == 3 and float(ds.FrameTime) == pytest.approx(66.7)
        assert ds.SeriesDescription == view.name
        frame = load_frame(path, view, frame_index=2, line_integrals=False)
        assert frame.image.shape == view.shape and np.isfinite(frame.image).all()
    # The CBCT holds the suggested target; the meshes read back as a transducer model.
    assert load_volume(lab.cbct).contains(lab.target_mm)[0]
    model = TransducerModel.from_meshes({p.stem: p for p in lab.transducer_meshes}, spacing_mm=1.0)
    assert all(n > 0 for n in model.n_points.values())


def load_flange_poses_from(data, key):
    from histostudy.robot import transform_from_pose

    return [transform_from_pose(p) for p in data[key]]


def test_the_same_seed_writes_the_same_files(lab, tmp_path):
    again = write_lab_dataset(tmp_path, seed=9, n_cine_frames=3, views=_small_views())
    for a, b in ((lab.cine[0], again.cine[0]), (lab.calibration_frames[2][1], again.calibration_frames[2][1]),
                 (lab.truth, again.truth)):
        assert a.read_bytes() == b.read_bytes()
    np.testing.assert_array_equal(load_volume(lab.cbct).data, load_volume(again.cbct).data)


def test_bad_arguments_are_refused_before_anything_is_written(tmp_path):
    for kwargs, match in (({"seed": -1}, "seed"), ({"n_cine_frames": 0}, "n_cine_frames"),
                          ({"frame_time_ms": 0.0}, "frame_time_ms")):
        with pytest.raises(ValueError, match=match):
            write_lab_dataset(tmp_path / "x", **kwargs)
    assert not (tmp_path / "x").exists()


def test_the_lab_scene_renders_render_frames_images_with_the_same_draws():
    from histostudy.imaging import random_background, render_frame
    from histostudy.study.targeting.setup import TargetingStudyConfig
    from histostudy.study.your_data.lab_dataset import LabScene
    from histostudy.transducer import pose_facing

    config, views = TargetingStudyConfig(n_experiments=1, background="phantom"), _small_views()
    scene = LabScene.draw(config, views, rng_scene=np.random.default_rng(1), rng_physical=np.random.default_rng(2),
                          render_spacing_mm=0.5)
    images = scene.render_pair(pose_facing(), np.random.default_rng(3))
    physical = TransducerModel.build_physical(spacing_mm=0.5, rng=np.random.default_rng(2))
    background, rng = random_background(np.random.default_rng(1), "phantom"), np.random.default_rng(3)
    frames = [render_frame(TransducerModel.build(spacing_mm=0.5), pose_facing(), v, rng=rng, physical=physical,
                           background=background, **config.frame_kwargs()) for v in views]
    for image, frame in zip(images, frames):
        np.testing.assert_array_equal(image, frame.image)
    with pytest.raises(ValueError, match="render_spacing_mm must be a finite spacing > 0 mm, got 0"):
        LabScene.draw(config, views, rng_scene=np.random.default_rng(1), rng_physical=np.random.default_rng(2),
                      render_spacing_mm=0)
