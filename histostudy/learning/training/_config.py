"""What a training run of a learned stage is (paper §II-B.2, §II-B.4): its configuration (a profile's
``[training.<task>]`` table), its stages and the frames each trains and validates on, and its result
(docs/training.md, "The training package").
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import torch

from histostudy.core import check_count, check_positive, is_real

from ..datasets import TASKS, RenderConfig
from ..nets import build_network

__all__ = ["FineTuneConfig", "SEGMENTATION_LOSSES", "TRAINING_TABLES", "TrainingConfig", "TrainingResult",
           "export_name", "run_frame_sets"]

#: The segmentation losses a profile may choose (:attr:`TrainingConfig.loss`).
SEGMENTATION_LOSSES = ("cross_entropy", "cross_entropy+dice")

#: A profile's ``[training.<table>]`` tables that ``histostudy train <table>`` runs: the table's
#: name -> ``(task, variant)``. The variant names what the network is for beyond its task
#: (``"tracking"``: the U-Net of ``pose.Tracker``'s fast warm path at input scale 0.25;
#: ``"tracking_fine"``: the U-Net that reads 0.5 and runs its levels at 0.25, docs/tracking.md;
#: ``"gpu"``: the study's network trained by the prepared GPU run, scripts/gpu_training_run.py) and
#: its exported name (:func:`export_name`); ``""`` for the study's networks.
TRAINING_TABLES = {"segmentation": ("segmentation", ""), "orientation": ("orientation", ""),
                   "segmentation_tracking": ("segmentation", "tracking"),
                   "segmentation_tracking_fine": ("segmentation", "tracking_fine"),
                   "segmentation_gpu": ("segmentation", "gpu"), "orientation_gpu": ("orientation", "gpu")}


def export_name(table: str, arch: str, profile: str) -> str:
    """The name of the weights ``histostudy train <table>`` exports to ``data/models``.

    Args:
        table: a key of :data:`TRAINING_TABLES` (``"segmentation"``, ``"segmentation_tracking"``, ...).
        arch: the network's architecture (``"unet"``, ``"vgg19"``).
        profile: the profile's name.

    Returns:
        ``<arch>_<profile>`` (``unet_standard``) for a task's own table, ``<arch>_<variant>`` for a
        variant of the ``standard`` profile (``unet_tracking``), ``<arch>_<variant>_<profile>`` else.

    Raises:
        ValueError: ``table`` is not a key of :data:`TRAINING_TABLES`.
    """
    if table not in TRAINING_TABLES:
        raise ValueError(f"table must be one of {sorted(TRAINING_TABLES)}, got {table!r}")
    variant = TRAINING_TABLES[table][1]
    if not variant:
        return f"{arch}_{profile}"
    return f"{arch}_{variant}" if profile == "standard" else f"{arch}_{variant}_{profile}"


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

    Raises:
        ValueError: ``max_minutes`` is not > 0 or None.
        TypeError: ``render`` is not a :class:`~histostudy.learning.datasets.RenderConfig`.
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
            check_count(getattr(self, name), f"fine_tune.{name}")
        check_positive(self.learning_rate, "fine_tune.learning_rate")
        if self.max_minutes is not None and not (self.max_minutes > 0):
            raise ValueError(f"fine_tune.max_minutes must be > 0 or None, got {self.max_minutes!r}")

    @classmethod
    def from_table(cls, table: dict, *, n_val: int) -> FineTuneConfig:
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
        teacher: segmentation only: a U-Net checkpoint trained at this ``scale`` whose arg-max labels
            replace the rendered frames' as targets, in training and validation (distillation,
            :mod:`~histostudy.learning.training._teacher`). Recorded with its SHA-256 in the
            exported manifest.
        fine_tune: a last ``finetune`` stage on frames of another rendering (:class:`FineTuneConfig`
            or its table), or None.

    Raises:
        ValueError: a field is out of its range or does not fit the task (the message names it).
        TypeError: ``render`` or ``fine_tune`` is of the wrong type.
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
    teacher: str | None = None
    fine_tune: FineTuneConfig | None = None

    def __post_init__(self):
        if self.task not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.task!r}")
        build_network(dict(self.network))  # a clear error now rather than after rendering
        for name in ("n_train", "n_val", "batch_size", "patience", "max_epochs", "crops_per_frame"):
            check_count(getattr(self, name), name)
        if self.batch_size > self.n_train:
            raise ValueError(f"batch_size ({self.batch_size}) must not exceed n_train ({self.n_train})")
        for name in ("learning_rate", "momentum"):
            check_positive(getattr(self, name), name, allow_zero=True)
        if not (is_real(self.lr_decay)
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
        if self.teacher is not None and (self.task != "segmentation" or not isinstance(self.teacher, str)
                                         or not self.teacher):
            raise ValueError(f"teacher must be None or the path of a U-Net checkpoint for a segmentation run, "
                             f"got {self.teacher!r} for task {self.task!r}")
        if isinstance(self.fine_tune, dict):
            object.__setattr__(self, "fine_tune", FineTuneConfig.from_table(self.fine_tune, n_val=self.n_val))
        elif self.fine_tune is not None and not isinstance(self.fine_tune, FineTuneConfig):
            raise TypeError(f"fine_tune must be a FineTuneConfig, a table or None, got {type(self.fine_tune).__name__}")
        if self.fine_tune is not None and self.batch_size > self.fine_tune.n_train:
            raise ValueError(f"batch_size ({self.batch_size}) must not exceed fine_tune.n_train "
                             f"({self.fine_tune.n_train})")

    @classmethod
    def from_table(cls, task: str, table: dict) -> TrainingConfig:
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


def resolve_device(name: str) -> torch.device:
    """The torch device of :attr:`TrainingConfig.device` (``"auto"``: CUDA when torch sees one)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but torch sees no CUDA device")
    return torch.device(name)


# --- the stages of a run --------------------------------------------------------------------------


def stage_names(cfg: TrainingConfig) -> list[str]:
    """The stages ``cfg`` runs, in order (docs/training.md)."""
    if cfg.task == "segmentation":
        stages = ["segment"]
    else:
        stages = (["classify"] if cfg.classification_epochs > 0 else []) + ["regress"]
    return stages + (["finetune"] if cfg.fine_tune is not None else [])


def stage_objective(cfg: TrainingConfig, stage: str) -> str:
    """The loss a stage trains: the fine-tune keeps the one of the stage before it."""
    if stage != "finetune":
        return stage
    return "segment" if cfg.task == "segmentation" else "regress"


def fine_tune_of(cfg: TrainingConfig) -> FineTuneConfig:
    """The fine-tune stage's configuration; ``ValueError`` where ``cfg`` has none (a ``finetune``
    stage then does not exist)."""
    if cfg.fine_tune is None:
        raise ValueError(f"the {cfg.task} run has no fine_tune table, so no 'finetune' stage")
    return cfg.fine_tune


def stage_frames(cfg: TrainingConfig, stage: str) -> tuple[RenderConfig, int, int]:
    """The rendering and the numbers of training and validation frames of ``stage``."""
    if stage == "finetune":
        fine_tune = fine_tune_of(cfg)
        return fine_tune.render, fine_tune.n_train, fine_tune.n_val
    return cfg.render, cfg.n_train, cfg.n_val


def run_frame_sets(cfg: TrainingConfig) -> list[tuple[RenderConfig, int, int]]:
    """The frame sets a run's stages train and validate on (to render them beforehand).

    Args:
        cfg: the run's :class:`TrainingConfig`.

    Returns:
        Every ``(render, n_train, n_val)`` of its stages, each once, in stage order.
    """
    sets = []
    for stage in stage_names(cfg):
        frames = stage_frames(cfg, stage)
        if frames not in sets:
            sets.append(frames)
    return sets
