"""One training loop for both learned stages (paper §II-B.2 and §II-B.4).

SGD with momentum 0.9, learning rate 0.001, mini-batches of 5 (the paper's values, profile
defaults), an epoch being one pass over the training frames; after each epoch the validation loss
is computed on a held-out split (its own seeds) and training stops when it has not improved for
``patience`` (3) epochs, when ``max_epochs`` is reached or when the wall-time budget
``max_minutes`` is spent. The best network (lowest validation loss) is kept.

- segmentation: the U-Net on random ``crop x crop`` patches of the frames downscaled by ``scale``
  (paper: 512x512 at full resolution), pixel-wise cross-entropy over the six classes.
- orientation: two stages (§II-B.4). ``classify``: VGG19 as a 36-class classifier of the nearest
  hemisphere orientation (cross-entropy); then its best weights become the regressor
  (:meth:`~histostudy.learning.nets.vgg.VGG19.to_regressor`) and ``regress`` trains azimuth and elevation
  with the loss ``sin(el)^2 wrap(d_az)^2 + d_el^2`` (rad²): the squared angle between predicted and
  true direction for small errors. ``wrap`` takes the azimuth difference into ``(-pi, pi]``, so a
  prediction of ``179°`` for ``-179°`` costs 2° and not 358°; the ``sin(el)`` weight says that the
  azimuth of a direction along the beam axis means nothing.

An optional last stage, ``finetune`` (:class:`FineTuneConfig`), goes on training the best network
of the stage before it, with that stage's loss, on frames of another rendering (e.g. the 0.125 mm
model of the held-out frames, after a long run on cheaper 0.47 mm frames), with its own training
and validation frames, learning rate and budget.

Checkpoints (:mod:`histostudy.learning.checkpoints`): after every epoch ``last.safetensors`` (network and
optimiser momentum, with ``state.json``: stage, epoch, steps, best loss, history) and, on a new
best, ``best-<stage>.safetensors`` — all written atomically, so an interrupted run resumes from
its last completed epoch with :func:`train` (``resume=True``). :func:`export` copies the best
network with its manifest (profile, seed, git commit, steps, validation metrics, sha256) to
``data/models``.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch.nn import functional as F
from torch.utils.data import DataLoader

from histostudy.core import atomic_write_json
from histostudy.transducer import FEATURE_CLASSES, Feature
from .checkpoints import MODELS_DIR, load_checkpoint, save_checkpoint
from .datasets import HybridFrames, HybridImageDataset, RenderConfig, TASKS, default_cache_dir
from .nets import build_network
from .orientation import N_ORIENTATION_CLASSES, hemisphere_angles

__all__ = ["FineTuneConfig", "SEGMENTATION_LOSSES", "TrainingConfig", "TrainingResult", "angle_loss", "dice_loss", "export",
           "train"]

#: The segmentation losses a profile may choose (:attr:`TrainingConfig.loss`).
SEGMENTATION_LOSSES = ("cross_entropy", "cross_entropy+dice")


@dataclass(frozen=True)
class FineTuneConfig:
    """The ``finetune`` stage: the run's best network trained on frames of another rendering.

    A profile's ``[training.<task>.fine_tune]`` table. The stage starts from the best network of
    the stage before it (orientation: ``regress``; segmentation: ``segment``) and keeps its loss,
    batch size, optimiser kind, patience and learning-rate decay; the optimiser's state starts
    afresh at ``learning_rate``.

    Attributes:
        render: the :class:`~histostudy.learning.datasets.RenderConfig` of its training and validation frames.
        n_train: training frames (split ``train`` of ``render``: the same poses as the run's first
            ``n_train`` frames, rendered this other way).
        n_val: validation frames (split ``val`` of ``render``).
        learning_rate: its starting learning rate (a fine-tune wants a smaller step than a fresh run).
        max_epochs: cap of the stage.
        max_minutes: wall-time budget of the stage alone, counted from its start (None: none);
            the run's ``max_minutes`` covers the stages before it.
    """

    render: RenderConfig
    n_train: int
    n_val: int
    learning_rate: float
    max_epochs: int = 50
    max_minutes: float | None = None

    def __post_init__(self):
        if not isinstance(self.render, RenderConfig):
            raise TypeError(f"fine_tune.render must be a RenderConfig, got {type(self.render).__name__}")
        for name in ("n_train", "n_val", "max_epochs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"fine_tune.{name} must be an integer >= 1, got {value!r}")
        if not (isinstance(self.learning_rate, (int, float)) and not isinstance(self.learning_rate, bool)
                and math.isfinite(self.learning_rate) and self.learning_rate > 0):
            raise ValueError(f"fine_tune.learning_rate must be a finite number > 0, got {self.learning_rate!r}")
        if self.max_minutes is not None and not (self.max_minutes > 0):
            raise ValueError(f"fine_tune.max_minutes must be > 0 or None, got {self.max_minutes!r}")

    @classmethod
    def from_table(cls, table: dict, *, n_val: int) -> "FineTuneConfig":
        """From a ``fine_tune`` table; its ``render`` sub-table is a RenderConfig, ``n_val`` defaults to the run's."""
        table = dict(table)
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"fine_tune has unknown keys {sorted(unknown)}; known: {sorted(known)}")
        missing = {"n_train", "learning_rate", "render"} - set(table)
        if missing:
            raise ValueError(f"fine_tune needs {sorted(missing)}")
        try:
            render = table.pop("render")
            render = render if isinstance(render, RenderConfig) else RenderConfig(**render)
        except TypeError as exc:
            raise ValueError(f"fine_tune.render: {exc}") from None
        return cls(render=render, **{"n_val": n_val, **table})


@dataclass(frozen=True)
class TrainingConfig:
    """Everything a training run depends on (a profile's ``[training.<task>]`` table).

    Attributes:
        task: ``"segmentation"`` or ``"orientation"``.
        network: the network config (:func:`histostudy.learning.nets.build_network`), e.g.
            ``{"arch": "unet", "base_width": 12, "depth": 4}``.
        scale: input downscale (U-Net here 0.5; VGG 0.25 as in §II-B.4).
        crop: square training crop in network pixels (segmentation; None: whole images).
        crops_per_frame: segmentation: crops of every training frame per epoch (each its own),
            so that an epoch of few cached frames is long enough for early stopping to mean
            something.
        n_train, n_val: frames in the training and validation splits.
        batch_size, learning_rate, momentum: SGD (paper: 5, 0.001, 0.9).
        optimizer: ``"sgd"`` (the paper's: SGD with ``momentum``) or ``"adam"`` (Adam with
            ``learning_rate`` and torch's default betas; ``momentum`` unused). The CPU-sized
            profile may use Adam: with a few thousand steps plain SGD at lr 0.001 leaves the
            thin classes and the orientation classifier untrained.
        patience: epochs without a lower validation loss before stopping (paper: 3).
        lr_decay: factor applied to the learning rate after every epoch without a lower
            validation loss (1: constant, as the paper says nothing of a schedule). With a
            factor < 1 a stage that stalls continues at a finer step before patience ends it;
            each stage starts again at ``learning_rate``.
        max_epochs: cap per stage.
        classification_epochs: cap of the orientation classifier stage (0: skip it).
        max_minutes: wall-time budget of the whole run (None: none).
        threads: torch CPU threads (None: torch's default).
        device: ``"auto"`` (CUDA when present), ``"cpu"`` or ``"cuda"``.
        render: the :class:`~histostudy.learning.datasets.RenderConfig` of the hybrid frames.
        cache: keep rendered frames on disk (under the cache folder) between epochs and runs.
        class_weights: segmentation only: a weight per class for the cross-entropy (None: all 1,
            the paper's loss as far as it says); rare thin classes may be weighted up.
        loss: segmentation only: ``"cross_entropy"`` (the paper's, with ``class_weights``) or
            ``"cross_entropy+dice"``: that plus the soft Dice loss of the five feature classes,
            averaged over classes (Milletari et al. 2016; the batch's pixels pooled per class, as
            Sudre et al. 2017's generalised Dice), so that a thin or rare class (gaps, screws, the
            inner boundary) weighs as much as the elements whatever its share of the pixels.
        init_weights: a checkpoint whose network (same config) starts the run instead of a random
            initialisation (fine-tuning); for an orientation run without classifier stage it may
            be the trained classifier, converted to the regressor (§II-B.4). Recorded with its
            SHA-256 in the exported manifest.
        fine_tune: a last ``finetune`` stage on frames of another rendering (:class:`FineTuneConfig`
            or its table), or None.
    """

    task: str
    network: dict
    scale: float
    crop: int | None = None
    crops_per_frame: int = 1
    n_train: int = 200
    n_val: int = 30
    batch_size: int = 5
    learning_rate: float = 1e-3
    momentum: float = 0.9
    optimizer: str = "sgd"
    patience: int = 3
    lr_decay: float = 1.0
    max_epochs: int = 50
    classification_epochs: int = 0
    max_minutes: float | None = None
    threads: int | None = None
    device: str = "auto"
    render: RenderConfig = field(default_factory=RenderConfig)
    cache: bool = True
    class_weights: tuple | None = None
    loss: str = "cross_entropy"
    init_weights: str | None = None
    fine_tune: FineTuneConfig | None = None

    def __post_init__(self):
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        build_network(dict(self.network))  # a clear error now rather than after rendering
        for name in ("n_train", "n_val", "batch_size", "patience", "max_epochs", "crops_per_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.batch_size > self.n_train:
            raise ValueError(f"batch_size ({self.batch_size}) must not exceed n_train ({self.n_train})")
        for name in ("learning_rate", "momentum"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not (isinstance(self.lr_decay, (int, float)) and not isinstance(self.lr_decay, bool)
                and 0 < self.lr_decay <= 1):
            raise ValueError(f"lr_decay must be a number in (0, 1], got {self.lr_decay!r}")
        if self.optimizer not in ("sgd", "adam"):
            raise ValueError(f"optimizer must be 'sgd' or 'adam', got {self.optimizer!r}")
        if self.max_minutes is not None and not (self.max_minutes > 0):
            raise ValueError(f"max_minutes must be > 0 or None, got {self.max_minutes!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"device must be 'auto', 'cpu' or 'cuda', got {self.device!r}")
        if not isinstance(self.render, RenderConfig):
            raise TypeError(f"render must be a RenderConfig, got {type(self.render).__name__}")
        if self.class_weights is not None:
            w = tuple(float(v) for v in self.class_weights)
            if self.task != "segmentation" or len(w) != 6 or not all(math.isfinite(v) and v > 0 for v in w):
                raise ValueError(f"class_weights must be None or 6 positive numbers for segmentation, got "
                                 f"{self.class_weights!r} for task {self.task!r}")
            object.__setattr__(self, "class_weights", w)
        if self.loss not in SEGMENTATION_LOSSES or (self.loss != "cross_entropy" and self.task != "segmentation"):
            raise ValueError(f"loss must be one of {SEGMENTATION_LOSSES} (a segmentation run), got {self.loss!r} "
                             f"for task {self.task!r}")
        if isinstance(self.fine_tune, dict):
            object.__setattr__(self, "fine_tune", FineTuneConfig.from_table(self.fine_tune, n_val=self.n_val))
        elif self.fine_tune is not None and not isinstance(self.fine_tune, FineTuneConfig):
            raise TypeError(f"fine_tune must be a FineTuneConfig, a table or None, got {type(self.fine_tune).__name__}")
        if self.fine_tune is not None and self.batch_size > self.fine_tune.n_train:
            raise ValueError(f"batch_size ({self.batch_size}) must not exceed fine_tune.n_train "
                             f"({self.fine_tune.n_train})")

    @classmethod
    def from_table(cls, task: str, table: dict) -> "TrainingConfig":
        """From a profile's ``[training.<task>]`` table; its ``render`` sub-table is a RenderConfig."""
        table = dict(table)
        known = {f.name for f in fields(cls)} - {"task"}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"[training.{task}] has unknown keys {sorted(unknown)}; known: {sorted(known)}")
        render = table.pop("render", {})
        try:
            render_cfg = RenderConfig(**render)
        except TypeError as exc:
            raise ValueError(f"[training.{task}.render]: {exc}") from None
        return cls(task=task, render=render_cfg, **table)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class TrainingResult:
    """What a run did: where its checkpoints are, the steps, the best validation metrics and why it stopped."""

    run_dir: Path
    best: Path
    steps: int
    epochs: int
    validation: dict
    stopped: str
    history: list


def angle_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean of ``sin(el)^2 wrap(az_p - az)^2 + (el_p - el)^2`` (rad²) over a batch of ``(az, el)`` rows."""
    d_az = pred[:, 0] - target[:, 0]
    d_az = torch.atan2(torch.sin(d_az), torch.cos(d_az))
    return (torch.sin(target[:, 1]) ** 2 * d_az ** 2 + (pred[:, 1] - target[:, 1]) ** 2).mean()


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but torch sees no CUDA device")
    return torch.device(name)


def _stages(cfg: TrainingConfig) -> list[str]:
    if cfg.task == "segmentation":
        stages = ["segment"]
    else:
        stages = (["classify"] if cfg.classification_epochs > 0 else []) + ["regress"]
    return stages + (["finetune"] if cfg.fine_tune is not None else [])


def _objective(cfg: TrainingConfig, stage: str) -> str:
    """The loss a stage trains: the fine-tune keeps the one of the stage before it."""
    if stage != "finetune":
        return stage
    return "segment" if cfg.task == "segmentation" else "regress"


def dice_loss(logits: torch.Tensor, labels: torch.Tensor, classes=tuple(int(k) for k in FEATURE_CLASSES),
              eps: float = 1.0) -> torch.Tensor:
    """``1 - mean_k Dice_k`` of the softmax of ``logits`` (B, C, H, W) against integer ``labels``
    (B, H, W), over ``classes``, each class's pixels pooled over the batch; ``eps`` keeps a class
    absent from the batch finite (its Dice then rewards predicting none of it)."""
    prob = torch.softmax(logits, dim=1)
    dices = []
    for k in classes:
        p, t = prob[:, k], (labels == k).to(prob.dtype)
        dices.append((2 * (p * t).sum() + eps) / (p.sum() + t.sum() + eps))
    return 1 - torch.stack(dices).mean()


def _loss(stage: str, net, batch, device, class_weights=None, kind: str = "cross_entropy"
          ) -> tuple[torch.Tensor, torch.Tensor]:
    x = batch["image"].to(device)
    if stage == "segment":
        y = batch["labels"].to(device)
        out = net(x)
        w = None if class_weights is None else torch.tensor(class_weights, dtype=out.dtype, device=device)
        loss = F.cross_entropy(out, y, weight=w)
        if kind == "cross_entropy+dice":
            loss = loss + dice_loss(out, y)
        return loss, out
    if stage == "classify":
        out = net(x)
        return F.cross_entropy(out, batch["class"].to(device)), out
    out = net(x)
    return angle_loss(out, batch["angles"].to(device)), out


@torch.no_grad()
def _validate(stage: str, net, loader, device, class_weights=None, kind: str = "cross_entropy") -> dict:
    net.eval()
    total, n = 0.0, 0
    correct, pixels = 0, 0
    intersection, union = np.zeros(len(Feature)), np.zeros(len(Feature))
    az_err, el_err = [], []
    for batch in loader:
        loss, out = _loss(stage, net, batch, device, class_weights, kind)
        b = batch["image"].shape[0]
        total += loss.item() * b
        n += b
        if stage == "segment":
            pred, ref = out.argmax(1).cpu(), batch["labels"]
            correct += int((pred == ref).sum())
            pixels += ref.numel()
            for k in range(len(Feature)):
                p, r = pred == k, ref == k
                intersection[k] += int((p & r).sum())
                union[k] += int((p | r).sum())
        elif stage == "classify":
            correct += int((out.argmax(1).cpu() == batch["class"]).sum())
            pixels += b
        else:
            p, t = out.double().cpu(), batch["angles"].double()
            d = p[:, 0] - t[:, 0]
            az_err.append(torch.atan2(torch.sin(d), torch.cos(d)).abs())
            el_err.append((p[:, 1] - t[:, 1]).abs())
    net.train()
    metrics = {"loss": total / max(n, 1)}
    if stage == "segment":
        metrics["pixel_accuracy"] = correct / max(pixels, 1)
        # per-class IoU of the validation pixels (NaN for a class absent from prediction and reference)
        for k in Feature:
            metrics[f"iou_{k.name.lower()}"] = float(intersection[k] / union[k]) if union[k] else float("nan")
    elif stage == "classify":
        metrics["class_accuracy"] = correct / max(pixels, 1)
    else:
        metrics["azimuth_mae_deg"] = math.degrees(torch.cat(az_err).mean().item())
        metrics["elevation_mae_deg"] = math.degrees(torch.cat(el_err).mean().item())
    return metrics


def _optimizer(cfg: TrainingConfig, net) -> torch.optim.Optimizer:
    if cfg.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    return torch.optim.SGD(net.parameters(), lr=cfg.learning_rate, momentum=cfg.momentum)


def _set_learning_rate(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        group["lr"] = lr


def _optim_tensors(opt: torch.optim.Optimizer) -> dict:
    """The optimiser's per-parameter state as tensors (SGD's momentum; Adam's moments and step)."""
    out = {}
    for i, state in opt.state_dict()["state"].items():
        for name, value in state.items():
            if value is not None:
                out[f"optim.{i}.{name}"] = torch.as_tensor(value)
    return out


def _load_optim(opt: torch.optim.Optimizer, tensors: dict) -> None:
    sd = opt.state_dict()
    state = {}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, i, name = key.split(".", 2)
            state.setdefault(int(i), {})[name] = value
    sd["state"] = state
    opt.load_state_dict(sd)


def _model_tensors(net) -> dict:
    return {f"model.{k}": v for k, v in net.state_dict().items()}


def stage_frames(cfg: TrainingConfig, stage: str) -> tuple[RenderConfig, int, int]:
    """The rendering and the numbers of training and validation frames of ``stage``."""
    if stage == "finetune":
        return cfg.fine_tune.render, cfg.fine_tune.n_train, cfg.fine_tune.n_val
    return cfg.render, cfg.n_train, cfg.n_val


def run_frame_sets(cfg: TrainingConfig) -> list[tuple[RenderConfig, int, int]]:
    """Every ``(render, n_train, n_val)`` the run's stages train and validate on, each once, in stage order."""
    sets = []
    for stage in _stages(cfg):
        frames = stage_frames(cfg, stage)
        if frames not in sets:
            sets.append(frames)
    return sets


def _loaders(cfg: TrainingConfig, seed: int, cache_dir, stage: str):
    render, n_train, n_val = stage_frames(cfg, stage)
    frames_kwargs = dict(config=render, cache_dir=cache_dir if cfg.cache else None)
    crop = cfg.crop if cfg.task == "segmentation" else None
    train_ds = HybridImageDataset(cfg.task, HybridFrames("train", seed, **frames_kwargs), n_train,
                                  scale=cfg.scale, crop=crop, augment=cfg.task == "orientation", seed=seed,
                                  repeats=cfg.crops_per_frame if cfg.task == "segmentation" else 1,
                                  keep_in_memory=True)
    val_ds = HybridImageDataset(cfg.task, HybridFrames("val", seed, **frames_kwargs), n_val,
                                scale=cfg.scale, crop=None, augment=False, seed=seed, keep_in_memory=True)
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


def train(cfg: TrainingConfig, run_dir, *, seed: int, profile: str = "", resume: bool = True,
          progress: bool = True, log: Callable[[str], None] = print, cache_dir=None) -> TrainingResult:
    """Train (or resume) the network of ``cfg`` in ``run_dir``; see the module docstring.

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
    """
    from tqdm.auto import tqdm

    if not isinstance(cfg, TrainingConfig):
        raise TypeError(f"cfg must be a TrainingConfig, got {type(cfg).__name__}")
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    device = _device(cfg.device)
    t_start = time.monotonic()
    stages = _stages(cfg)
    state_path = run_dir / "state.json"
    cfg_dict = json.loads(json.dumps(cfg.to_dict()))

    torch.manual_seed(seed)
    net_config = dict(cfg.network)
    if cfg.task == "orientation":
        net_config.setdefault("n_classes", N_ORIENTATION_CLASSES)
        net_config["head"] = "classifier" if stages[0] == "classify" else "regressor"
    net = build_network(net_config)
    state = {"stage": stages[0], "epoch": 0, "steps": 0, "best_loss": None, "bad_epochs": 0,
             "history": [], "finished": False, "stopped": "", "elapsed_s": 0.0, "best": {},
             "learning_rate": cfg.learning_rate}
    if cfg.init_weights:
        tensors, init_manifest = load_checkpoint(cfg.init_weights)
        init_config = init_manifest["config"]
        model = {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}
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
            raise ValueError(f"init_weights {str(cfg.init_weights)!r} has config {init_config}, expected {net.config} "
                             f"(or its classifier for a regression run)")
        state["init_weights"] = {"path": str(cfg.init_weights), "sha256": init_manifest["sha256"],
                                 "training_steps": init_manifest.get("training_steps"),
                                 "validation": init_manifest.get("validation")}
    opt = _optimizer(cfg, net)
    if resume and state_path.is_file():
        previous = json.loads(state_path.read_text())
        if _identity(previous.get("config", {})) != _identity(cfg_dict) or previous.get("seed") != seed:
            raise ValueError(f"run folder {str(run_dir)!r} holds a run with another configuration or seed; "
                             f"use another folder or resume=False")
        state = previous["state"]
        # the stopping rules are checked again below, with this call's values
        state["finished"] = False
        tensors, manifest = load_checkpoint(run_dir / "last.safetensors")
        net = build_network(manifest["config"])
        net.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
        opt = _optimizer(cfg, net)
        _load_optim(opt, tensors)
        _set_learning_rate(opt, state.get("learning_rate", cfg.learning_rate))
        log(f"resumed {cfg.task} from {run_dir} at stage {state['stage']}, epoch {state['epoch']}, "
            f"step {state['steps']}")
    else:
        # a fresh run: checkpoints of an earlier run in this folder must not be taken for this one's
        for stale in [*run_dir.glob("best-*"), *run_dir.glob("last.*"), state_path]:
            stale.unlink(missing_ok=True)
    net.to(device).train()
    train_ds, val_loader = _loaders(cfg, seed, cache_dir, state["stage"])
    elapsed_before = state["elapsed_s"]

    def elapsed_s() -> float:
        return elapsed_before + time.monotonic() - t_start

    def save_state():
        state["elapsed_s"] = elapsed_s()
        atomic_write_json(state_path, {"config": cfg_dict, "seed": seed, "profile": profile, "state": state})

    while not state["finished"]:
        stage = state["stage"]
        if stage == "finetune":
            cap, budget = cfg.fine_tune.max_epochs, cfg.fine_tune.max_minutes
            spent_s = elapsed_s() - state.get("stage_start_s", 0.0)
        else:
            cap = cfg.classification_epochs if stage == "classify" else cfg.max_epochs
            budget, spent_s = cfg.max_minutes, elapsed_s()
        stop = ""
        if state["bad_epochs"] >= cfg.patience:
            stop = f"no lower validation loss for {cfg.patience} epochs"
        elif state["epoch"] >= cap:
            stop = f"reached {cap} epochs"
        elif budget is not None and spent_s > 60 * budget:
            stop = f"spent the {budget} min budget"
        if stop:
            log(f"{cfg.task}/{stage}: stopped after epoch {state['epoch']}: {stop}")
            state.setdefault("stage_stops", {})[stage] = stop
            following = stages[stages.index(stage) + 1] if stage != stages[-1] else None
            best_path = run_dir / f"best-{stage}.safetensors"
            # the run's budget ends the stages it covers; the fine-tune has a budget of its own
            if following is not None and best_path.is_file() and ("budget" not in stop or following == "finetune"):
                tensors, _ = load_checkpoint(best_path)
                net.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
                if stage == "classify":
                    net.cpu().to_regressor(hemisphere_angles(net.config["n_classes"]))
                net.to(device).train()
                lr = cfg.fine_tune.learning_rate if following == "finetune" else cfg.learning_rate
                opt = _optimizer(cfg, net)
                _set_learning_rate(opt, lr)
                state.update(stage=following, epoch=0, best_loss=None, bad_epochs=0, learning_rate=lr,
                             stage_start_s=elapsed_s())
                if following == "finetune":
                    train_ds, val_loader = _loaders(cfg, seed, cache_dir, following)
                save_checkpoint(run_dir / "last", {**_model_tensors(net), **_optim_tensors(opt)}, net.config)
                save_state()
                continue
            state.update(finished=True, stopped=stop)
            save_state()
            break
        epoch = state["epoch"]
        train_ds.set_epoch(epoch + 1000 * stages.index(stage))
        order_seed, dropout_seed = np.random.SeedSequence(
            [seed, TASKS.index(cfg.task), stages.index(stage), epoch]).generate_state(2)
        gen = torch.Generator().manual_seed(int(order_seed))
        # dropout draws from torch's global generator: seeded per epoch, a resumed run draws what an
        # uninterrupted one would have
        torch.manual_seed(int(dropout_seed))
        loader = DataLoader(train_ds, batch_size=cfg.batch_size, shuffle=True, drop_last=True, generator=gen)
        running = 0.0
        bar = tqdm(loader, desc=f"{cfg.task}/{stage} epoch {epoch + 1}", disable=not progress, leave=False)
        for i, batch in enumerate(bar):
            loss, _ = _loss(_objective(cfg, stage), net, batch, device, cfg.class_weights, cfg.loss)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            state["steps"] += 1
            running += loss.item()
            bar.set_postfix(loss=f"{running / (i + 1):.4f}")
        bar.close()
        metrics = _validate(_objective(cfg, stage), net, val_loader, device, cfg.class_weights, cfg.loss)
        metrics.update(train_loss=running / max(len(loader), 1), stage=stage, epoch=epoch + 1, steps=state["steps"],
                       learning_rate=opt.param_groups[0]["lr"])
        state["history"].append(metrics)
        state["epoch"] = epoch + 1
        improved = state["best_loss"] is None or metrics["loss"] < state["best_loss"]
        if improved:
            state.update(best_loss=metrics["loss"], bad_epochs=0)
            state["best"][stage] = metrics
            save_checkpoint(run_dir / f"best-{stage}", _model_tensors(net), net.config, stage=stage,
                            training_steps=state["steps"], validation=metrics, seed=seed, profile=profile)
        else:
            state["bad_epochs"] += 1
            if cfg.lr_decay < 1:
                state["learning_rate"] = state.get("learning_rate", cfg.learning_rate) * cfg.lr_decay
                _set_learning_rate(opt, state["learning_rate"])
        save_checkpoint(run_dir / "last", {**_model_tensors(net), **_optim_tensors(opt)}, net.config)
        save_state()
        log(f"{cfg.task}/{stage} epoch {epoch + 1}: " + ", ".join(
            f"{k} {v:.4g}" for k, v in metrics.items() if isinstance(v, float)) + (" *" if improved else ""))

    # the last stage that kept a network (a stage stopped by a budget before its first epoch has none)
    final_stage = next((st for st in reversed(stages) if (run_dir / f"best-{st}.safetensors").is_file()), stages[0])
    best = run_dir / f"best-{final_stage}.safetensors"
    return TrainingResult(run_dir=run_dir, best=best, steps=state["steps"], epochs=state["epoch"],
                          validation=state["best"].get(final_stage, {}), stopped=state["stopped"],
                          history=state["history"])


def _validation_split(cfg: TrainingConfig, stage: str | None) -> str:
    render, _, n_val = stage_frames(cfg, stage or "")
    return (f"{n_val} frames of split 'val' rendered from the {render.render_spacing_mm:g} mm model, "
            f"background {render.background!r}")


def export(result: TrainingResult, cfg: TrainingConfig, name: str, *, seed: int, profile: str,
           models_dir=None) -> Path:
    """Copy the run's best network to ``<models_dir>/<name>.safetensors`` with the full manifest."""
    tensors, manifest = load_checkpoint(result.best)
    model = {k: v for k, v in tensors.items() if k.startswith("model.")}
    state = json.loads((result.run_dir / "state.json").read_text())["state"]
    dest = (MODELS_DIR if models_dir is None else Path(models_dir)) / name
    return save_checkpoint(
        dest, model, manifest["config"], task=cfg.task, profile=profile, seed=seed,
        input_scale=cfg.scale, training_steps=manifest.get("training_steps"), total_steps=result.steps,
        validation=manifest.get("validation"), validation_split=_validation_split(cfg, manifest.get("stage")),
        stages=state.get("best", {}), stopped=result.stopped, stage_stops=state.get("stage_stops", {}),
        training_minutes=state.get("elapsed_s", 0.0) / 60.0, device=str(_device(cfg.device)),
        init_weights=state.get("init_weights"),
        training_config=json.loads(json.dumps(cfg.to_dict())),
    )
