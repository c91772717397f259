"""Exporting a trained network (paper §II-B.2, §II-B.4): the run's best network copied to
``data/models`` with the manifest a reader of the results needs — profile, seed, git commit,
training steps, the validation split and its metrics (losses in the stage's unit: cross-entropy,
or rad² for the angle loss; angle errors in degrees), the stages' stops, the training time in
minutes and the SHA-256 of the weights (:mod:`histostudy.learning.checkpoints`).
"""

from __future__ import annotations

import json
from pathlib import Path

from .checkpoints import MODELS_DIR, load_checkpoint, save_checkpoint
from .training_config import TrainingConfig, TrainingResult, resolve_device, stage_frames

__all__ = ["export"]


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
        training_minutes=state.get("elapsed_s", 0.0) / 60.0, device=str(resolve_device(cfg.device)),
        init_weights=state.get("init_weights"), teacher=state.get("teacher"),
        training_config=json.loads(json.dumps(cfg.to_dict())),
    )
