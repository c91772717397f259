"""Tests of histostudy.learning.training._loop (and its export) on tiny networks and frames: resume, early stopping,
both stages, fine-tuning, export, the CLI."""

import json
import math

import pytest
import torch

from histostudy.learning import LearnedOrientation, RenderConfig, TrainingConfig, export, train
from histostudy.learning.checkpoints import load_checkpoint, load_network
from histostudy.learning.orientation import hemisphere_angles

TINY = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))


def _seg(**kw):
    base = dict(task="segmentation", network={"arch": "unet", "base_width": 2, "depth": 2}, scale=0.5, crop=32,
                n_train=4, n_val=2, batch_size=2, max_epochs=2, render=TINY)
    return TrainingConfig(**{**base, **kw})


class _Stop(Exception):
    pass


def _stop_after_first_epoch(msg):
    """A log callback that interrupts a run once its first epoch is checkpointed."""
    if "epoch 1:" in msg:
        raise _Stop


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("frames")


def test_the_loss_is_a_segmentation_choice_and_changes_the_validation_loss(tmp_path, cache):
    with pytest.raises(ValueError, match="loss"):
        _seg(loss="focal")
    with pytest.raises(ValueError, match="loss"):
        TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25,
                       loss="cross_entropy+dice")
    plain = train(_seg(max_epochs=1, learning_rate=0.0), tmp_path / "ce", seed=3, progress=False,
                  log=lambda m: None, cache_dir=cache)
    dice = train(_seg(max_epochs=1, learning_rate=0.0, loss="cross_entropy+dice"), tmp_path / "dice", seed=3,
                 progress=False, log=lambda m: None, cache_dir=cache)
    # the same untrained network: the Dice term adds a loss in (0, 1]
    assert 0 < dice.history[0]["loss"] - plain.history[0]["loss"] <= 1
    assert 0 <= plain.history[0]["iou_background"] <= 1 and "iou_screws" in plain.history[0]


def test_interrupted_run_resumes_to_the_same_weights(tmp_path, cache):
    cfg = _seg()
    full = train(cfg, tmp_path / "full", seed=3, progress=False, log=lambda m: None, cache_dir=cache)

    with pytest.raises(_Stop):
        train(cfg, tmp_path / "cut", seed=3, progress=False, log=_stop_after_first_epoch, cache_dir=cache)
    state = json.loads((tmp_path / "cut" / "state.json").read_text())["state"]
    assert state["epoch"] == 1 and not state["finished"]
    resumed = train(cfg, tmp_path / "cut", seed=3, progress=False, log=lambda m: None, cache_dir=cache)
    assert resumed.steps == full.steps == 2 * (4 // 2)
    a, _ = load_checkpoint(tmp_path / "full" / "last.safetensors")
    b, _ = load_checkpoint(tmp_path / "cut" / "last.safetensors")
    assert a.keys() == b.keys() and any(k.startswith("optim.") for k in a)
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    assert not list(tmp_path.rglob("*.tmp*"))
    with pytest.raises(ValueError, match="another configuration"):
        train(_seg(crop=16), tmp_path / "cut", seed=3, progress=False, log=lambda m: None, cache_dir=cache)


def test_early_stopping_after_patience_epochs_without_improvement(tmp_path, cache):
    # learning rate 0 and a network without batch norm: the validation loss stays exactly the same
    cfg = TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, n_train=4,
                         n_val=2, batch_size=2, learning_rate=0.0, patience=2, max_epochs=10, render=TINY)
    res = train(cfg, tmp_path / "run", seed=3, progress=False, log=lambda m: None, cache_dir=cache)
    assert res.epochs == 3 and "2 epochs" in res.stopped
    losses = [h["loss"] for h in res.history]
    assert losses[1] == losses[0] == losses[2]


def test_orientation_classifier_then_regressor_and_export(tmp_path, cache):
    cfg = TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, n_train=4,
                         n_val=2, batch_size=2, classification_epochs=1, max_epochs=1, render=TINY)
    res = train(cfg, tmp_path / "run", seed=4, progress=False, log=lambda m: None, cache_dir=cache)
    assert [h["stage"] for h in res.history] == ["classify", "regress"]
    assert "class_accuracy" in res.history[0] and "azimuth_mae_deg" in res.history[1]
    manifest_path = export(res, cfg, "vgg19_test", seed=4, profile="test", models_dir=tmp_path / "models")
    manifest = json.loads(manifest_path.read_text())
    assert manifest["config"]["head"] == "regressor" and manifest["input_scale"] == 0.25
    assert manifest["training_steps"] == 4 and manifest["task"] == "orientation"
    assert math.isfinite(manifest["validation"]["azimuth_mae_deg"])
    source = LearnedOrientation.load(manifest_path.with_suffix(".safetensors"))
    net, _ = load_network(manifest_path.with_suffix(".safetensors"))
    assert net.config["head"] == "regressor" and source.scale == 0.25
    # a regression-only run may start from the trained classifier (converted as in §II-B.4)
    classifier = tmp_path / "run" / "best-classify.safetensors"
    frozen = TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, n_train=4,
                            n_val=2, batch_size=2, max_epochs=1, learning_rate=0.0, render=TINY,
                            init_weights=str(classifier))
    reg = train(frozen, tmp_path / "reg", seed=5, progress=False, log=lambda m: None, cache_dir=cache)
    a, _ = load_checkpoint(classifier)
    b, _ = load_checkpoint(reg.best)
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    torch.testing.assert_close(b["model.regressor.bias"], torch.tensor([0.0, 1.0]))
    # ... and becomes a (cos, sin) regressor whose azimuth rows start as the classes' (cos, sin)
    cos_sin = TrainingConfig(task="orientation", scale=0.25, n_train=4, n_val=2, batch_size=2, max_epochs=1,
                             network={"arch": "vgg19", "width": 1 / 32, "angle_encoding": "cos_sin"},
                             learning_rate=0.0, render=TINY, init_weights=str(classifier))
    reg = train(cos_sin, tmp_path / "reg_cs", seed=5, progress=False, log=lambda m: None, cache_dir=cache)
    c, manifest = load_checkpoint(reg.best)
    assert manifest["config"]["angle_encoding"] == "cos_sin" and manifest["config"]["head"] == "regressor"
    azimuths = torch.as_tensor(hemisphere_angles(36)[:, 0], dtype=torch.float32)
    torch.testing.assert_close(c["model.regressor.weight"][:2], torch.stack([azimuths.cos(), azimuths.sin()]))
    torch.testing.assert_close(c["model.regressor.bias"], torch.tensor([0.0, 0.0, 1.0]))



def test_cli_train_exports_weights_with_manifest(tmp_path, capsys, monkeypatch):
    from histostudy.cli import main

    monkeypatch.setenv("HISTOSTUDY_CACHE", str(tmp_path / "cache"))
    profile = tmp_path / "tiny.toml"
    profile.write_text('name = "tiny"\nseed = 11\n\n[training.segmentation]\n'
                       'network = { arch = "unet", base_width = 2, depth = 2 }\nscale = 0.5\ncrop = 32\n'
                       'n_train = 2\nn_val = 1\nbatch_size = 2\nmax_epochs = 1\n'
                       'render = { render_spacing_mm = 0.47, label_spacing_mm = 0.47, detector = [240, 320] }\n')
    assert main(["train", "segmentation", "--profile", str(profile), "--render-workers", "0"]) == 2
    assert "--render-workers must be >= 1, got 0" in capsys.readouterr().err
    assert main(["train", "segmentation", "--profile", str(profile), "--render-only", "--render-workers", "2"]) == 0
    assert "rendered 3 uncached frames" in capsys.readouterr().out
    assert not (tmp_path / "cache" / "runs").exists()  # rendered, nothing trained
    code = main(["train", "segmentation", "--profile", str(profile), "--models-dir", str(tmp_path / "models"),
                 "--no-progress", "--render-workers", "2"])
    assert code == 0
    out = capsys.readouterr().out
    assert "rendered 0 uncached frames" in out  # the 1 validation + 2 training frames were rendered above
    assert "exported" in out and (tmp_path / "cache" / "runs" / "segmentation-tiny" / "state.json").is_file()
    manifest = json.loads((tmp_path / "models" / "unet_tiny.json").read_text())
    assert manifest["profile"] == "tiny" and manifest["seed"] == 11 and manifest["training_steps"] == 1
    assert main(["train", "orientation", "--profile", str(profile)]) == 2
    assert "no [training.orientation]" in capsys.readouterr().err


def test_a_run_may_resume_with_another_budget(tmp_path, cache):
    # one thread throughout: a different thread count changes float reductions in the last bits
    first = train(_seg(max_epochs=1, threads=1), tmp_path / "run", seed=3, progress=False, log=lambda m: None,
                  cache_dir=cache)
    assert first.epochs == 1
    with pytest.raises(ValueError, match="another configuration"):
        train(_seg(max_epochs=1, crop=16), tmp_path / "run", seed=3, progress=False, log=lambda m: None,
              cache_dir=cache)
    again = train(_seg(max_epochs=1, max_minutes=0.001, threads=1), tmp_path / "run", seed=3, progress=False,
                  log=lambda m: None, cache_dir=cache)
    assert again.steps == first.steps and again.stopped == first.stopped
    # a larger epoch cap continues the finished run along the trajectory of a run started with it
    longer = train(_seg(max_epochs=2, threads=1), tmp_path / "run", seed=3, progress=False, log=lambda m: None,
                   cache_dir=cache)
    straight = train(_seg(max_epochs=2, threads=1), tmp_path / "straight", seed=3, progress=False,
                     log=lambda m: None, cache_dir=cache)
    assert longer.epochs == straight.epochs == 2 and longer.steps == straight.steps
    a, _ = load_checkpoint(tmp_path / "run" / "last.safetensors")
    b, _ = load_checkpoint(tmp_path / "straight" / "last.safetensors")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    (tmp_path / "run" / "best-regress.safetensors").write_bytes(b"left over from another run")
    fresh = train(_seg(max_epochs=1, crop=16), tmp_path / "run", seed=3, resume=False, progress=False,
                  log=lambda m: None, cache_dir=cache)
    assert fresh.best.name == "best-segment.safetensors"
    assert not (tmp_path / "run" / "best-regress.safetensors").exists()


def test_class_weights_and_warm_start(tmp_path, cache):
    with pytest.raises(ValueError, match="class_weights"):
        _seg(class_weights=(1, 2, 3))
    with pytest.raises(ValueError, match="class_weights"):
        TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25,
                       class_weights=(1,) * 6)
    first = train(_seg(max_epochs=1), tmp_path / "a", seed=3, progress=False, log=lambda m: None, cache_dir=cache)
    # a zero learning rate keeps the warm start's weights: the network is exactly the first run's
    cfg = _seg(max_epochs=1, learning_rate=0.0, class_weights=(1, 1.5, 4, 6, 8, 8), init_weights=str(first.best))
    second = train(cfg, tmp_path / "b", seed=99, progress=False, log=lambda m: None, cache_dir=cache)
    a, _ = load_checkpoint(first.best)
    b, _ = load_checkpoint(second.best)
    for k in a:
        if "running" not in k and "num_batches" not in k:  # batch-norm statistics still move in train mode
            torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    # the weighted validation loss differs from the unweighted one on the same network
    assert second.history[0]["loss"] != pytest.approx(first.history[0]["loss"], rel=1e-3)
    manifest = json.loads(export(second, cfg, "warm", seed=99, profile="t", models_dir=tmp_path / "m").read_text())
    assert manifest["init_weights"]["sha256"] == json.loads(first.best.with_suffix(".json").read_text())["sha256"]
    with pytest.raises(ValueError, match="expected"):
        train(_seg(network={"arch": "unet", "base_width": 4, "depth": 2}, init_weights=str(first.best)),
              tmp_path / "c", seed=3, progress=False, log=lambda m: None, cache_dir=cache)


def test_adam_runs_resume_bit_for_bit_and_keep_their_moments(tmp_path, cache):
    cfg = _seg(optimizer="adam", max_epochs=2)
    full = train(cfg, tmp_path / "full", seed=4, progress=False, log=lambda m: None, cache_dir=cache)

    with pytest.raises(_Stop):
        train(cfg, tmp_path / "cut", seed=4, progress=False, log=_stop_after_first_epoch, cache_dir=cache)
    train(cfg, tmp_path / "cut", seed=4, progress=False, log=lambda m: None, cache_dir=cache)
    a, _ = load_checkpoint(tmp_path / "full" / "last.safetensors")
    b, _ = load_checkpoint(tmp_path / "cut" / "last.safetensors")
    names = {k.rsplit(".", 1)[1] for k in a if k.startswith("optim.")}
    assert {"exp_avg", "exp_avg_sq", "step"} <= names
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    assert full.steps == 4
    with pytest.raises(ValueError, match="optimizer"):
        _seg(optimizer="rmsprop")


def test_crops_per_frame_makes_longer_epochs_of_distinct_crops(tmp_path, cache):
    from histostudy.learning import HybridFrames
    from histostudy.learning.datasets import HybridImageDataset

    frames = HybridFrames("train", 5, TINY, cache_dir=cache)
    ds = HybridImageDataset("segmentation", frames, 2, scale=0.5, crop=32, seed=5, repeats=3)
    assert len(ds) == 6
    items = [ds[i]["image"] for i in range(6)]
    assert not torch.equal(items[0], items[1])  # two crops of frame 0
    whole = HybridImageDataset("segmentation", frames, 2, scale=0.5, crop=None, seed=5, repeats=3)
    # items 0-2 are frame 0, items 3-5 frame 1
    torch.testing.assert_close(whole[1]["image"], whole[2]["image"])
    assert not torch.equal(whole[2]["image"], whole[3]["image"])
    with pytest.raises(IndexError):
        ds[6]
    with pytest.raises(ValueError, match="repeats"):
        HybridImageDataset("segmentation", frames, 2, scale=0.5, repeats=0)
    res = train(_seg(crops_per_frame=2, max_epochs=1), tmp_path / "run", seed=5, progress=False,
                log=lambda m: None, cache_dir=cache)
    assert res.steps == 4 * 2 // 2
    with pytest.raises(ValueError, match="crops_per_frame"):
        _seg(crops_per_frame=0)


def test_learning_rate_decays_after_each_epoch_without_improvement_and_resumes(tmp_path, cache, monkeypatch):
    import histostudy.learning.training._loop as training

    losses = iter([1.0, 0.9, 0.95, 0.97, 0.8] * 2)
    real_validate = training.validation_metrics

    def scripted(*args, **kwargs):
        metrics = real_validate(*args, **kwargs)
        metrics["loss"] = next(losses)
        return metrics

    monkeypatch.setattr(training, "validation_metrics", scripted)
    cfg = _seg(optimizer="adam", learning_rate=1e-3, lr_decay=0.5, patience=5, max_epochs=5)
    full = train(cfg, tmp_path / "full", seed=6, progress=False, log=lambda m: None, cache_dir=cache)
    # the rate an epoch trained with: halved after epochs 3 and 4 (no lower loss), kept after 1, 2
    assert [h["learning_rate"] for h in full.history] == pytest.approx([1e-3, 1e-3, 1e-3, 5e-4, 2.5e-4])
    assert full.validation["loss"] == 0.8 and full.validation["learning_rate"] == pytest.approx(2.5e-4)

    def stop_after_fourth_epoch(msg):
        if "epoch 4:" in msg:
            raise _Stop

    with pytest.raises(_Stop):
        train(cfg, tmp_path / "cut", seed=6, progress=False, log=stop_after_fourth_epoch, cache_dir=cache)
    resumed = train(cfg, tmp_path / "cut", seed=6, progress=False, log=lambda m: None, cache_dir=cache)
    assert resumed.history[-1]["learning_rate"] == pytest.approx(2.5e-4)  # the decayed rate survives the restart
    a, _ = load_checkpoint(tmp_path / "full" / "last.safetensors")
    b, _ = load_checkpoint(tmp_path / "cut" / "last.safetensors")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    for bad in (0, 1.5, True, "0.5"):
        with pytest.raises(ValueError, match="lr_decay"):
            _seg(lr_decay=bad)


# The fine-tune's frames: the same poses, rendered another way (another splat jitter: another cache key).
TINY_FINE = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320), splat_sigma_mm=0.25)


def _orient_fine_tune(**fine):
    fine_tune = {**dict(render=TINY_FINE, n_train=2, n_val=2, learning_rate=5e-4, max_epochs=2), **fine}
    return TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, n_train=4,
                          n_val=2, batch_size=2, max_epochs=1, optimizer="adam", threads=1, render=TINY,
                          fine_tune=fine_tune)


def _stop_in_fine_tune(msg):
    if "finetune epoch 1:" in msg:
        raise _Stop


def test_fine_tune_stage_trains_the_best_network_on_frames_of_another_rendering(tmp_path, cache):
    from histostudy.learning import HybridFrames

    cfg = _orient_fine_tune()
    assert cfg.fine_tune.render == TINY_FINE and cfg.fine_tune.n_val == 2
    full = train(cfg, tmp_path / "full", seed=7, progress=False, log=lambda m: None, cache_dir=cache)
    assert [h["stage"] for h in full.history] == ["regress", "finetune", "finetune"]
    assert full.best.name == "best-finetune.safetensors" and full.steps == 2 + 2 * 1
    assert full.history[1]["learning_rate"] == 5e-4 and "azimuth_mae_deg" in full.history[1]
    fine_frames = HybridFrames("train", 7, TINY_FINE, cache_dir=cache)
    assert fine_frames.cached(0) and fine_frames.cached(1) and not fine_frames.cached(2)
    assert HybridFrames("val", 7, TINY_FINE, cache_dir=cache).cached(1)

    # the fine-tune starts from the best regressor: its first validation, with the learning rate at 0,
    # would be that network's loss on the fine-tune's validation frames; here it is computed directly
    import histostudy.learning.training._loop as training

    regressor, _ = load_network(tmp_path / "full" / "best-regress.safetensors")
    _, val_loader = training._loaders(cfg, 7, cache, "finetune")
    frozen = train(_orient_fine_tune(max_epochs=1, learning_rate=1e-30), tmp_path / "frozen", seed=7,
                   progress=False, log=lambda m: None, cache_dir=cache)
    expected = training.validation_metrics("regress", regressor, val_loader, torch.device("cpu"))
    assert frozen.history[1]["loss"] == pytest.approx(expected["loss"], rel=1e-4)
    # ... the same poses as the regression's validation frames, rendered the other way
    _, regress_loader = training._loaders(cfg, 7, cache, "regress")
    fine_batch, regress_batch = next(iter(val_loader)), next(iter(regress_loader))
    torch.testing.assert_close(fine_batch["angles"], regress_batch["angles"], rtol=0, atol=0)
    assert not torch.allclose(fine_batch["image"], regress_batch["image"], atol=1e-2)

    # interrupted inside the fine-tune, the run resumes there, to the same weights
    with pytest.raises(_Stop):
        train(cfg, tmp_path / "cut", seed=7, progress=False, log=_stop_in_fine_tune, cache_dir=cache)
    state = json.loads((tmp_path / "cut" / "state.json").read_text())["state"]
    assert (state["stage"], state["epoch"]) == ("finetune", 1)
    resumed = train(cfg, tmp_path / "cut", seed=7, progress=False, log=lambda m: None, cache_dir=cache)
    assert resumed.steps == full.steps
    a, _ = load_checkpoint(tmp_path / "full" / "last.safetensors")
    b, _ = load_checkpoint(tmp_path / "cut" / "last.safetensors")
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)
    # its budget is a run control; its frames are not
    train(_orient_fine_tune(max_minutes=30.0), tmp_path / "cut", seed=7, progress=False, log=lambda m: None,
          cache_dir=cache)
    with pytest.raises(ValueError, match="another configuration"):
        train(_orient_fine_tune(n_train=4), tmp_path / "cut", seed=7, progress=False, log=lambda m: None,
              cache_dir=cache)

    manifest = json.loads(export(full, cfg, "vgg_ft", seed=7, profile="t", models_dir=tmp_path / "m").read_text())
    assert manifest["validation"]["stage"] == "finetune" and set(manifest["stages"]) == {"regress", "finetune"}
    assert manifest["validation_split"].startswith("2 frames of split 'val' rendered from the 0.47 mm model")
    assert manifest["training_config"]["fine_tune"]["render"]["splat_sigma_mm"] == 0.25


def test_fine_tune_budget_of_its_own_and_bad_tables(tmp_path, cache):
    # a fine-tune whose budget is spent before its first epoch leaves the regressor as the run's best
    res = train(_orient_fine_tune(max_minutes=1e-9), tmp_path / "run", seed=7, progress=False,
                log=lambda m: None, cache_dir=cache)
    assert [h["stage"] for h in res.history] == ["regress"] and res.best.name == "best-regress.safetensors"
    state = json.loads((tmp_path / "run" / "state.json").read_text())["state"]
    assert state["stage_stops"]["finetune"].startswith("spent the 1e-09 min budget")

    table = {"network": {"arch": "vgg19", "width": 1 / 32}, "scale": 0.25, "n_val": 3,
             "fine_tune": {"n_train": 5, "learning_rate": 1e-4, "render": {"render_spacing_mm": 0.125}}}
    cfg = TrainingConfig.from_table("orientation", table)
    assert cfg.fine_tune.render.render_spacing_mm == 0.125 and cfg.fine_tune.n_val == 3
    from histostudy.learning import run_frame_sets

    assert run_frame_sets(cfg) == [(cfg.render, 200, 3), (cfg.fine_tune.render, 5, 3)]
    without = TrainingConfig.from_table("orientation", {**table, "fine_tune": None})
    assert run_frame_sets(without) == [(cfg.render, 200, 3)]
    for fine, match in [({"n_train": 5, "render": {}}, r"fine_tune needs \['learning_rate'\]"),
                        ({**table["fine_tune"], "epochs": 2}, r"fine_tune has unknown keys \['epochs'\]"),
                        ({**table["fine_tune"], "n_train": 0}, "fine_tune.n_train must be an integer >= 1, got 0"),
                        ({**table["fine_tune"], "learning_rate": 0.0}, "fine_tune.learning_rate must be"),
                        ({**table["fine_tune"], "render": {"spacing": 1}}, "fine_tune.render:"),
                        ({**table["fine_tune"], "n_train": 4}, r"batch_size \(5\) must not exceed fine_tune.n_train")]:
        with pytest.raises(ValueError, match=match):
            TrainingConfig.from_table("orientation", {**table, "fine_tune": fine})
    with pytest.raises(TypeError, match="fine_tune must be a FineTuneConfig"):
        TrainingConfig(task="orientation", network={"arch": "vgg19", "width": 1 / 32}, scale=0.25, fine_tune=3)


def test_cli_prerenders_the_fine_tune_frames_too(tmp_path, capsys, monkeypatch):
    from histostudy.cli import main

    monkeypatch.setenv("HISTOSTUDY_CACHE", str(tmp_path / "cache"))
    profile = tmp_path / "tiny.toml"
    render = "{ render_spacing_mm = 0.47, label_spacing_mm = 0.47, detector = [240, 320]%s }"
    profile.write_text('name = "tiny"\nseed = 11\n\n[training.orientation]\n'
                       'network = { arch = "vgg19", width = 0.03125 }\nscale = 0.25\n'
                       'n_train = 2\nn_val = 1\nbatch_size = 2\nmax_epochs = 1\n'
                       f'render = {render % ""}\n'
                       'fine_tune = { n_train = 2, n_val = 1, learning_rate = 0.0005, max_epochs = 1, '
                       f'render = {render % ", splat_sigma_mm = 0.25"} }}\n')
    code = main(["train", "orientation", "--profile", str(profile), "--models-dir", str(tmp_path / "models"),
                 "--no-progress", "--render-workers", "2"])
    assert code == 0
    assert "rendered 6 uncached frames" in capsys.readouterr().out  # 1 + 2 frames of each rendering
    manifest = json.loads((tmp_path / "models" / "vgg19_tiny.json").read_text())
    assert manifest["validation"]["stage"] == "finetune" and manifest["training_steps"] == 2


def test_prerender_run_renders_each_stage_s_missing_frames_once(tmp_path):
    from histostudy.learning import prerender_run

    render = {"render_spacing_mm": 0.47, "label_spacing_mm": 0.47, "detector": [240, 320]}
    cfg = TrainingConfig.from_table("orientation", {
        "network": {"arch": "vgg19", "width": 1 / 32}, "scale": 0.25, "n_train": 2, "n_val": 1, "batch_size": 2,
        "render": render, "fine_tune": {"n_train": 2, "n_val": 1, "learning_rate": 5e-4,
                                        "render": {**render, "splat_sigma_mm": 0.25}}})
    assert prerender_run(cfg, 11, cache_dir=tmp_path) == 6  # 2 + 1 frames of each of the two renderings
    assert prerender_run(cfg, 11, cache_dir=tmp_path, workers=2) == 0  # all cached now
    assert prerender_run(cfg, 12, cache_dir=tmp_path) == 6  # another seed: other frames
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        prerender_run(cfg, 11, cache_dir=tmp_path, workers=0)
