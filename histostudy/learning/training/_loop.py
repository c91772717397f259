"""The training loop of both learned stages (paper §II-B.2, §II-B.4): SGD or Adam over epochs with
early stopping on a held-out split, atomic checkpoints after every epoch and a bit-for-bit resume
(docs/training.md, "The training package").
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from histostudy.core import atomic_write_json

from ..checkpoints import load_checkpoint, save_checkpoint
from ..datasets import TASKS, HybridFrames, HybridImageDataset, default_cache_dir
from ..nets import build_network
from ..orientation import N_ORIENTATION_CLASSES, hemisphere_angles
from ._config import (
    TrainingConfig,
    TrainingResult,
    fine_tune_of,
    resolve_device,
    stage_frames,
    stage_names,
    stage_objective,
)
from ._losses import stage_loss, validation_metrics
from ._optim import _load_optim, _model_state, _model_tensors, _optim_tensors, _optimizer, _set_learning_rate
from ._teacher import load_teacher, teacher_labeller

__all__ = ["train"]


def _loaders(cfg: TrainingConfig, seed: int, cache_dir, stage: str, target_labels=None):
    render, n_train, n_val = stage_frames(cfg, stage)
    frames_kwargs = dict(config=render, cache_dir=cache_dir if cfg.cache else None)
    crop = cfg.crop if cfg.task == "segmentation" else None
    train_ds = HybridImageDataset(cfg.task, HybridFrames("train", seed, **frames_kwargs), n_train,
                                  scale=cfg.scale, crop=crop, augment=cfg.task == "orientation", seed=seed,
                                  repeats=cfg.crops_per_frame if cfg.task == "segmentation" else 1,
                                  keep_in_memory=True, target_labels=target_labels)
    val_ds = HybridImageDataset(cfg.task, HybridFrames("val", seed, **frames_kwargs), n_val,
                                scale=cfg.scale, crop=None, augment=False, seed=seed, keep_in_memory=True,
                                target_labels=target_labels)
    val_loader = DataLoader(val_ds, batch_size=1 if cfg.task == "segmentation" else cfg.batch_size, shuffle=False)
    return train_ds, val_loader


#: Settings that control a run but not what it computes: a run may resume with other values. The
#: stopping rules are among them: a run stopped by its budget, epoch cap or patience goes on when
#: resumed with a larger one, along the same trajectory as a run started with it.
_RUN_CONTROLS = ("max_minutes", "threads", "device", "patience", "max_epochs")


def _identity(cfg_dict: dict) -> dict:
    identity = {k: v for k, v in cfg_dict.items() if k not in _RUN_CONTROLS}
    if identity.get("fine_tune"):
        identity["fine_tune"] = {k: v for k, v in identity["fine_tune"].items() if k not in _RUN_CONTROLS}
    return identity



def _warm_start(init_weights, net):
    """``(network, record)``: ``net`` with the weights of the checkpoint ``init_weights`` (same
    config, or for a regressor a trained classifier converted as in §II-B.4), and what the exported
    manifest records of that checkpoint."""
    tensors, init_manifest = load_checkpoint(init_weights)
    init_config = init_manifest["config"]
    model = _model_state(tensors)

    # a classifier's angle encoding is only what its regressor will be: any classifier will do
    def without_encoding(config):
        return {k: v for k, v in config.items() if k != "angle_encoding"}

    if without_encoding(init_config) == without_encoding({**net.config, "head": "classifier"}) \
            and net.config.get("head") == "regressor":
        # a trained 36-class classifier starting the regression: the conversion of §II-B.4
        net = build_network({**net.config, "head": "classifier"})
        net.load_state_dict(model)
        net.to_regressor(hemisphere_angles(net.config["n_classes"]))
    elif init_config == net.config:
        net.load_state_dict(model)
    else:
        raise ValueError(f"init_weights {str(init_weights)!r} has config {init_config}, expected {net.config} "
                         f"(or its classifier for a regression run)")
    record = {"path": str(init_weights), "sha256": init_manifest["sha256"],
              "training_steps": init_manifest.get("training_steps"), "validation": init_manifest.get("validation")}
    return net, record


def train(cfg: TrainingConfig, run_dir, *, seed: int, profile: str = "", resume: bool = True,
          progress: bool = True, log: Callable[[str], None] = print, cache_dir=None) -> TrainingResult:
    """Train (or resume) the network of ``cfg`` in ``run_dir`` (docs/training.md, "The training package").

    Args:
        cfg: the :class:`TrainingConfig`.
        run_dir: the run's folder (checkpoints and ``state.json``).
        seed: the study seed: frames, initial weights and batch order derive from it.
        profile: the profile name (recorded).
        resume: continue from ``run_dir``'s last checkpoint when there is one (its configuration
            must be the same, except the run controls ``max_minutes``, ``threads``, ``device``,
            ``patience`` and ``max_epochs``: a finished run goes on when they allow more); False
            starts afresh.
        progress: show a tqdm progress bar per epoch.
        cache_dir: folder of the rendered-frame cache (default :func:`default_cache_dir`).

    Returns:
        The :class:`~histostudy.learning.training._config.TrainingResult`: the best checkpoint, steps,
        epochs, validation metrics, why it stopped and the history.

    Raises:
        TypeError: ``cfg`` is not a :class:`TrainingConfig`.
        ValueError: ``resume`` and ``run_dir`` holds a run of another configuration or seed; device
            ``"cuda"`` without a CUDA device.
    """
    if not isinstance(cfg, TrainingConfig):
        raise TypeError(f"cfg must be a TrainingConfig, got {type(cfg).__name__}")
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    device = resolve_device(cfg.device)
    t_start = time.monotonic()
    stages = stage_names(cfg)
    state_path = run_dir / "state.json"
    cfg_dict = json.loads(json.dumps(cfg.to_dict()))

    net, state, teacher, opt = _fresh_start(cfg, seed, stages, device)
    if resume and state_path.is_file():
        net, opt, state = _resume(cfg, run_dir, cfg_dict, seed, log)
    else:
        # a fresh run: checkpoints of an earlier run in this folder must not be taken for this one's
        for stale in [*run_dir.glob("best-*"), *run_dir.glob("last.*"), state_path]:
            stale.unlink(missing_ok=True)
    net.to(device).train()
    target_labels = None if teacher is None else teacher_labeller(teacher, device)
    run = _Run(cfg, run_dir, seed=seed, profile=profile, log=log, cache_dir=cache_dir, device=device, stages=stages,
               cfg_dict=cfg_dict, state=state, t_start=t_start, net=net, opt=opt, target_labels=target_labels,
               progress=progress)
    run.run()
    return _result(run_dir, stages, run.state)


def _fresh_state(cfg: TrainingConfig, stages: list[str]) -> dict:
    """The checkpointed state of a run that has not trained yet: first stage, epoch 0, no steps,
    no best validation loss (``elapsed_s`` in seconds, ``learning_rate`` the configured one)."""
    return {"stage": stages[0], "epoch": 0, "steps": 0, "best_loss": None, "bad_epochs": 0,
            "history": [], "finished": False, "stopped": "", "elapsed_s": 0.0, "best": {},
            "learning_rate": cfg.learning_rate}


def _fresh_start(cfg: TrainingConfig, seed: int, stages: list[str], device):
    """``(net, state, teacher, opt)`` of a run starting afresh: the network initialised from
    ``seed`` (for orientation a 36-class classifier when the run starts with ``classify``, else the
    regressor of §II-B.4), warm-started from ``cfg.init_weights`` when given, the teacher of
    ``cfg.teacher`` (or None) and the optimiser; the state records the warm start and teacher."""
    torch.manual_seed(seed)
    net_config = dict(cfg.network)
    if cfg.task == "orientation":
        net_config.setdefault("n_classes", N_ORIENTATION_CLASSES)
        net_config["head"] = "classifier" if stages[0] == "classify" else "regressor"
    net = build_network(net_config)
    state = _fresh_state(cfg, stages)
    if cfg.init_weights:
        net, state["init_weights"] = _warm_start(cfg.init_weights, net)
    teacher = None
    if cfg.teacher:
        teacher, state["teacher"] = load_teacher(cfg.teacher, cfg.scale, device)
    return net, state, teacher, _optimizer(cfg, net)


def _resume(cfg: TrainingConfig, run_dir: Path, cfg_dict: dict, seed: int, log: Callable[[str], None]):
    """``(net, opt, state)`` of the run in ``run_dir`` at its last completed epoch (network,
    optimiser state and learning rate from ``last.safetensors``); ``ValueError`` when the folder
    holds a run of another configuration (run controls aside) or seed."""
    previous = json.loads((run_dir / "state.json").read_text())
    if _identity(previous.get("config", {})) != _identity(cfg_dict) or previous.get("seed") != seed:
        raise ValueError(f"run folder {str(run_dir)!r} holds a run with another configuration or seed; "
                         f"use another folder or resume=False")
    state = previous["state"]
    # the stopping rules are checked again below, with this call's values
    state["finished"] = False
    tensors, manifest = load_checkpoint(run_dir / "last.safetensors")
    net = build_network(manifest["config"])
    net.load_state_dict(_model_state(tensors))
    opt = _optimizer(cfg, net)
    _load_optim(opt, tensors)
    _set_learning_rate(opt, state.get("learning_rate", cfg.learning_rate))
    log(f"resumed {cfg.task} from {run_dir} at stage {state['stage']}, epoch {state['epoch']}, "
        f"step {state['steps']}")
    return net, opt, state


def _stop_reason(cfg: TrainingConfig, state: dict, stage: str, elapsed_s: float) -> str:
    """Why ``stage`` stops before its next epoch ("" to go on): ``patience`` epochs without a lower
    validation loss, its epoch cap, or its budget in minutes spent (the run's since its start, the
    fine-tune's since the fine-tune started; ``elapsed_s`` in seconds)."""
    if stage == "finetune":
        cap, budget = fine_tune_of(cfg).max_epochs, fine_tune_of(cfg).max_minutes
        spent_s = elapsed_s - state.get("stage_start_s", 0.0)
    else:
        cap = cfg.classification_epochs if stage == "classify" else cfg.max_epochs
        budget, spent_s = cfg.max_minutes, elapsed_s
    stop = ""
    if state["bad_epochs"] >= cfg.patience:
        stop = f"no lower validation loss for {cfg.patience} epochs"
    elif state["epoch"] >= cap:
        stop = f"reached {cap} epochs"
    elif budget is not None and spent_s > 60 * budget:
        stop = f"spent the {budget} min budget"
    return stop


class _Run:
    """A training run in progress in its folder (docs/training.md, "The training package"): the
    configuration, the clock, the network and optimiser, the current stage's data and the state checkpointed after every
    epoch (``state.json``, times in seconds)."""

    def __init__(self, cfg: TrainingConfig, run_dir: Path, *, seed: int, profile: str, log: Callable[[str], None],
                 cache_dir: Path, device, stages: list[str], cfg_dict: dict, state: dict, t_start: float, net, opt,
                 target_labels, progress: bool):
        self.cfg, self.run_dir, self.seed, self.profile, self.log = cfg, run_dir, seed, profile, log
        self.cache_dir, self.device, self.stages, self.cfg_dict = cache_dir, device, stages, cfg_dict
        self.state, self.t_start, self.net, self.opt = state, t_start, net, opt
        self.target_labels, self.progress = target_labels, progress
        self.train_ds, self.val_loader = _loaders(cfg, seed, cache_dir, state["stage"], target_labels)
        self.elapsed_before = state["elapsed_s"]

    def elapsed_s(self) -> float:
        """Seconds this run has trained, over all its calls of :func:`train`."""
        return self.elapsed_before + time.monotonic() - self.t_start

    def save_state(self) -> None:
        """Write ``state.json`` (configuration, seed, profile, state) atomically."""
        self.state["elapsed_s"] = self.elapsed_s()
        atomic_write_json(self.run_dir / "state.json", {"config": self.cfg_dict, "seed": self.seed,
                                                         "profile": self.profile, "state": self.state})

    def save_last(self) -> None:
        """Checkpoint the network and the optimiser's state as ``last.safetensors``."""
        save_checkpoint(self.run_dir / "last", {**_model_tensors(self.net), **_optim_tensors(self.opt)},
                        self.net.config)

    def run(self) -> None:
        """Train epoch after epoch, stage after stage, until the last stage stops."""
        state = self.state
        while not state["finished"]:
            stage = state["stage"]
            stop = _stop_reason(self.cfg, state, stage, self.elapsed_s())
            if stop:
                if self.stop_stage(stage, stop):
                    continue
                state.update(finished=True, stopped=stop)
                self.save_state()
                break
            self.epoch(stage)

    def stop_stage(self, stage: str, stop: str) -> bool:
        """Record why ``stage`` stopped; start the following stage from its best network and return
        True, unless it was the last stage, it kept no network, or the run's budget stopped it
        (which ends every stage it covers; the fine-tune has a budget of its own)."""
        state = self.state
        self.log(f"{self.cfg.task}/{stage}: stopped after epoch {state['epoch']}: {stop}")
        state.setdefault("stage_stops", {})[stage] = stop
        following = self.stages[self.stages.index(stage) + 1] if stage != self.stages[-1] else None
        best_path = self.run_dir / f"best-{stage}.safetensors"
        # the run's budget ends the stages it covers; the fine-tune has a budget of its own
        if following is not None and best_path.is_file() and ("budget" not in stop or following == "finetune"):
            self.start_stage(stage, following, best_path)
            return True
        return False

    def start_stage(self, stage: str, following: str, best_path: Path) -> None:
        """Go on from ``stage``'s best network (``best_path``; a classifier becomes the regressor of
        §II-B.4) to ``following``, with a fresh optimiser at its learning rate and, for the
        fine-tune, its own frames; checkpoint."""
        cfg, state, net = self.cfg, self.state, self.net
        tensors, _ = load_checkpoint(best_path)
        net.load_state_dict(_model_state(tensors))
        if stage == "classify":
            net.cpu().to_regressor(hemisphere_angles(net.config["n_classes"]))
        net.to(self.device).train()
        lr = fine_tune_of(cfg).learning_rate if following == "finetune" else cfg.learning_rate
        self.opt = _optimizer(cfg, net)
        _set_learning_rate(self.opt, lr)
        state.update(stage=following, epoch=0, best_loss=None, bad_epochs=0, learning_rate=lr,
                     stage_start_s=self.elapsed_s())
        if following == "finetune":
            self.train_ds, self.val_loader = _loaders(cfg, self.seed, self.cache_dir, following, self.target_labels)
        self.save_last()
        self.save_state()

    def train_epoch(self, stage: str, epoch: int) -> tuple[float, int]:
        """``(summed loss, batches)`` of one pass over the training frames of ``stage``, its batch
        order and dropout drawn from seeds of (seed, task, stage, epoch)."""
        cfg, state, stages = self.cfg, self.state, self.stages
        self.train_ds.set_epoch(epoch + 1000 * stages.index(stage))
        from tqdm.auto import tqdm

        order_seed, dropout_seed = np.random.SeedSequence(
            [self.seed, TASKS.index(cfg.task), stages.index(stage), epoch]).generate_state(2)
        gen = torch.Generator().manual_seed(int(order_seed))
        # dropout draws from torch's global generator: seeded per epoch, a resumed run draws what an
        # uninterrupted one would have
        torch.manual_seed(int(dropout_seed))
        loader = DataLoader(self.train_ds, batch_size=cfg.batch_size, shuffle=True, drop_last=True, generator=gen)
        running = 0.0
        bar = tqdm(loader, desc=f"{cfg.task}/{stage} epoch {epoch + 1}", disable=not self.progress, leave=False)
        for i, batch in enumerate(bar):
            loss, _ = stage_loss(stage_objective(cfg, stage), self.net, batch, self.device, cfg.class_weights, cfg.loss)
            self.opt.zero_grad(set_to_none=True)
            loss.backward()
            self.opt.step()
            state["steps"] += 1
            running += loss.item()
            bar.set_postfix(loss=f"{running / (i + 1):.4f}")
        bar.close()
        return running, len(loader)

    def epoch(self, stage: str) -> None:
        """Train one epoch of ``stage``, validate, keep the network on a new best (else count the
        epoch as bad and decay the learning rate by ``lr_decay``), checkpoint and log."""
        cfg, state, net = self.cfg, self.state, self.net
        epoch = state["epoch"]
        running, n_batches = self.train_epoch(stage, epoch)
        metrics = validation_metrics(stage_objective(cfg, stage), net, self.val_loader, self.device, cfg.class_weights,
                                     cfg.loss)
        metrics.update(train_loss=running / max(n_batches, 1), stage=stage, epoch=epoch + 1, steps=state["steps"],
                       learning_rate=self.opt.param_groups[0]["lr"])
        state["history"].append(metrics)
        state["epoch"] = epoch + 1
        improved = state["best_loss"] is None or metrics["loss"] < state["best_loss"]
        if improved:
            state.update(best_loss=metrics["loss"], bad_epochs=0)
            state["best"][stage] = metrics
            save_checkpoint(self.run_dir / f"best-{stage}", _model_tensors(net), net.config, stage=stage,
                            training_steps=state["steps"], validation=metrics, seed=self.seed, profile=self.profile)
        else:
            state["bad_epochs"] += 1
            if cfg.lr_decay < 1:
                state["learning_rate"] = state.get("learning_rate", cfg.learning_rate) * cfg.lr_decay
                _set_learning_rate(self.opt, state["learning_rate"])
        self.save_last()
        self.save_state()
        self.log(f"{cfg.task}/{stage} epoch {epoch + 1}: " + ", ".join(
            f"{k} {v:.4g}" for k, v in metrics.items() if isinstance(v, float)) + (" *" if improved else ""))


def _result(run_dir: Path, stages: list[str], state: dict) -> TrainingResult:
    """The :class:`TrainingResult` of a finished run: the best network of the last stage that kept
    one (a stage stopped by a budget before its first epoch has none)."""
    final_stage = next((st for st in reversed(stages) if (run_dir / f"best-{st}.safetensors").is_file()), stages[0])
    best = run_dir / f"best-{final_stage}.safetensors"
    return TrainingResult(run_dir=run_dir, best=best, steps=state["steps"], epochs=state["epoch"],
                          validation=state["best"].get(final_stage, {}), stopped=state["stopped"],
                          history=state["history"])
