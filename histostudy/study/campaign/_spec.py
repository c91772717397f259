"""A training campaign's definition: ``data/campaigns/<name>/campaign.toml``, the training table it
runs (as a profile's ``[training.<task>]``), its seed and its held-out evaluation."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from histostudy.core import check_count
from histostudy.core.provenance import REPO_ROOT
from histostudy.learning import MODELS_DIR, TrainingConfig

__all__ = ["CAMPAIGNS_DIR", "CampaignSpec", "load_campaign"]

#: Where the campaigns' definitions, ledgers and restart weights live (committed with the code).
CAMPAIGNS_DIR = REPO_ROOT / "data" / "campaigns"

_NAME = re.compile(r"[a-z0-9][a-z0-9_.-]*")
_TOP_KEYS = {"description", "seed", "training", "evaluation"}
_EVALUATION_KEYS = {"frames", "render", "baseline"}
#: the network a campaign of each task is compared with by default: the shipped one
_SHIPPED_BASELINE = {"segmentation": "unet_standard", "orientation": "vgg19_standard"}


@dataclass(frozen=True)
class CampaignSpec:
    """One campaign: a training run that goes on over many calls, on many machines (docs/campaigns.md).

    Attributes:
        name: the campaign's folder name under :data:`CAMPAIGNS_DIR`.
        folder: that folder (``campaign.toml``, ``ledger.json``, the committed restart weights).
        description: one sentence: what the campaign tries.
        seed: the training frames', initial weights' and batch order's seed.
        training: the checked :class:`~histostudy.learning.TrainingConfig` (its ``max_minutes`` set by
            each step; ``init_weights`` resolved against the repository root).
        eval_frames: held-out frames per evaluation (split ``eval`` of a seed drawn after the step).
        eval_render: keyword arguments of the held-out frames' :class:`~histostudy.learning.RenderConfig`
            (default: the study's: reference renderer, 0.125 mm models, mixed backgrounds).
        baseline: the network each step's candidate is compared with, frame by frame, on the same
            held-out frames (``[evaluation] baseline``: a path from the repository root, or ``false``
            for none; default: the shipped network of the task, ``data/models/unet_standard`` or
            ``vgg19_standard``); None: no comparison.
    """

    name: str
    folder: Path
    description: str
    seed: int
    training: TrainingConfig
    eval_frames: int = 40
    eval_render: dict = dataclasses.field(default_factory=dict)
    baseline: Path | None = None

    @property
    def task(self) -> str:
        """``"segmentation"`` (U-Net) or ``"orientation"`` (VGG19)."""
        return self.training.task

    @property
    def ledger_path(self) -> Path:
        """The campaign's ledger, ``<folder>/ledger.json``."""
        return self.folder / "ledger.json"

    @property
    def restart_weights(self) -> Path:
        """The committed float16 restart weights, ``<folder>/restart.safetensors`` (may not exist)."""
        return self.folder / "restart.safetensors"


def load_campaign(name: str, campaigns_dir=None) -> CampaignSpec:
    """Read and check ``<campaigns_dir>/<name>/campaign.toml``.

    Args:
        name: the campaign's name (lower case letters, digits, ``_ . -``).
        campaigns_dir: the folder of the campaigns (default :data:`CAMPAIGNS_DIR`).

    Returns:
        The :class:`CampaignSpec`.

    Raises:
        ValueError: a bad name, a missing definition, or a definition whose keys or training table
            are wrong (the message names the file and the key).
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"name must be a campaign's folder name (lower case letters, digits, '_', '.', '-'), "
                         f"got {name!r}")
    root = CAMPAIGNS_DIR if campaigns_dir is None else Path(campaigns_dir)
    path = root / name / "campaign.toml"
    if not path.is_file():
        known = sorted(p.parent.name for p in root.glob("*/campaign.toml")) if root.is_dir() else []
        raise ValueError(f"name {name!r}: no campaign definition at {path} (campaigns here: {known or 'none'})")
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    unknown = set(table) - _TOP_KEYS
    if unknown or "training" not in table or "seed" not in table:
        raise ValueError(f"{path}: keys {sorted(table)}; expected 'seed' and 'training', optionally "
                         f"'description' and 'evaluation' (unknown: {sorted(unknown)})")
    training = dict(table["training"])
    task = training.pop("task", None)
    if task not in ("segmentation", "orientation"):
        raise ValueError(f"{path}: [training] task must be 'segmentation' or 'orientation', got {task!r}")
    if training.get("init_weights"):
        init = Path(training["init_weights"])
        training["init_weights"] = str(init if init.is_absolute() else REPO_ROOT / init)
    if "max_minutes" in training:
        raise ValueError(f"{path}: [training] max_minutes is set by each step (histostudy campaign run "
                         f"--minutes), not by the campaign")
    try:
        config = TrainingConfig.from_table(task, training)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: [training]: {exc}") from None
    evaluation = dict(table.get("evaluation", {}))
    if set(evaluation) - _EVALUATION_KEYS:
        raise ValueError(f"{path}: [evaluation] has keys {sorted(evaluation)}; known: {sorted(_EVALUATION_KEYS)}")
    eval_frames = evaluation.get("frames", 40)
    check_count(eval_frames, "[evaluation] frames")
    baseline = evaluation.get("baseline", True)
    if baseline is True:
        baseline = MODELS_DIR / f"{_SHIPPED_BASELINE[task]}.safetensors"
    elif isinstance(baseline, str) and baseline.endswith(".safetensors"):
        baseline = Path(baseline) if Path(baseline).is_absolute() else REPO_ROOT / baseline
        if not baseline.is_file():
            raise ValueError(f"{path}: [evaluation] baseline {str(baseline)!r} does not exist")
    elif baseline is not False:
        raise ValueError(f"{path}: [evaluation] baseline must be a .safetensors path from the repository root or "
                         f"false, got {baseline!r}")
    check_count(table["seed"], "seed", minimum=0)
    return CampaignSpec(name=name, folder=root / name, description=str(table.get("description", "")),
                        seed=int(table["seed"]), training=config, eval_frames=int(eval_frames),
                        eval_render=dict(evaluation.get("render", {})), baseline=baseline or None)
