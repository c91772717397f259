"""Tests of histostudy.learning.training._teacher (a segmentation run on a teacher network's labels) on
tiny networks and frames: the student that is its teacher agrees with it everywhere, the targets are
the teacher's arg-max, the manifest records the teacher, and bad teachers are refused."""

import json

import numpy as np
import pytest
import torch

from histostudy.learning import HybridFrames, RenderConfig, TrainingConfig, build_network, export, train
from histostudy.learning.checkpoints import load_checkpoint, save_checkpoint
from histostudy.learning.datasets import HybridImageDataset
from histostudy.learning.training._teacher import load_teacher, teacher_labeller

TINY = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))


def _seg(**kw):
    base = dict(task="segmentation", network={"arch": "unet", "base_width": 2, "depth": 2}, scale=0.5, crop=None,
                n_train=4, n_val=2, batch_size=2, max_epochs=1, render=TINY)
    return TrainingConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def teacher(tmp_path_factory):
    """A tiny U-Net trained one epoch on the rendered labels and exported (its manifest has the input scale)."""
    root = tmp_path_factory.mktemp("teacher")
    cfg = _seg()
    run = train(cfg, root / "run", seed=3, progress=False, log=lambda m: None, cache_dir=root / "frames")
    path = export(run, cfg, "teacher", seed=3, profile="t", models_dir=root / "models")
    return run, path.with_suffix(".safetensors"), root / "frames"


def test_targets_are_the_teachers_arg_max_on_the_same_input(teacher):
    _, path, frames = teacher
    net, record = load_teacher(path, 0.5, torch.device("cpu"))
    assert record["sha256"] == json.loads(path.with_suffix(".json").read_text())["sha256"]
    assert record["input_scale"] == 0.5 and not any(p.requires_grad for p in net.parameters())
    ds = HybridImageDataset("segmentation", HybridFrames("train", 3, config=TINY, cache_dir=frames), 2, scale=0.5,
                            target_labels=teacher_labeller(net, torch.device("cpu")))
    truth = HybridImageDataset("segmentation", HybridFrames("train", 3, config=TINY, cache_dir=frames), 2, scale=0.5)
    item, reference = ds[1], truth[1]
    torch.testing.assert_close(item["image"], reference["image"], rtol=0, atol=0)
    with torch.no_grad():
        expected = net(reference["image"][None]).argmax(dim=1)[0]
    assert item["labels"].dtype == torch.int64 and torch.equal(item["labels"], expected)
    # the teacher's labels are not the rendered ones: the dataset really swapped them
    assert not torch.equal(item["labels"], reference["labels"])


def test_a_student_that_is_its_teacher_agrees_with_it_and_the_manifest_says_whose_labels(teacher, tmp_path):
    """Started from the teacher's weights at learning rate 0, the student labels the validation
    frames as its teacher does (the batch-norm statistics, which move in train mode, aside: > 99 %),
    while the same network scored against the rendered labels agrees far less."""
    run, path, frames = teacher
    cfg = _seg(learning_rate=0.0, init_weights=str(run.best), teacher=str(path))
    student = train(cfg, tmp_path / "student", seed=3, progress=False, log=lambda m: None, cache_dir=frames)
    assert student.validation["pixel_accuracy"] > 0.99
    assert run.validation["pixel_accuracy"] < student.validation["pixel_accuracy"] - 0.05
    manifest = json.loads(export(student, cfg, "student", seed=3, profile="t", models_dir=tmp_path / "m").read_text())
    assert manifest["teacher"]["sha256"] == json.loads(path.with_suffix(".json").read_text())["sha256"]
    assert manifest["training_config"]["teacher"] == str(path)


def test_bad_teachers_and_targets_are_refused_by_name(teacher, tmp_path):
    run, path, frames = teacher
    with pytest.raises(ValueError, match="teacher must be None or the path of a U-Net checkpoint.*orientation"):
        TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, teacher=str(path))
    with pytest.raises(ValueError, match="teacher must be None"):
        _seg(teacher="")
    with pytest.raises(ValueError, match="reads input scale 0.5, but the run trains at scale 0.25"):
        load_teacher(path, 0.25, torch.device("cpu"))
    with pytest.raises(ValueError, match="reads input scale None"):
        load_teacher(run.best, 0.5, torch.device("cpu"))  # a run's checkpoint, not exported: no input scale
    split = HybridFrames("train", 3, config=TINY, cache_dir=frames)
    with pytest.raises(ValueError, match="target_labels must be None or a callable"):
        HybridImageDataset("orientation", split, 2, scale=0.25, target_labels=lambda image: image)
    wrong_grid = HybridImageDataset("segmentation", split, 2, scale=0.5,
                                    target_labels=lambda image: np.zeros((3, 3), np.int64))
    with pytest.raises(ValueError, match="target_labels gave labels of shape \\(3, 3\\)"):
        wrong_grid[0]
    vgg = build_network({"arch": "vgg19", "width": 1 / 32, "n_classes": 36})
    vgg_path = save_checkpoint(tmp_path / "vgg", {f"model.{k}": v for k, v in vgg.state_dict().items()}, vgg.config,
                               input_scale=0.5)
    with pytest.raises(ValueError, match="is a 'vgg19' network; expected a U-Net"):
        load_teacher(vgg_path.with_suffix(".safetensors"), 0.5, torch.device("cpu"))
    assert load_checkpoint(path)[1]["input_scale"] == 0.5
