"""Exporting a trained network (paper §II-B.2, §II-B.4): the run's best network copied to
``data/models`` with the manifest a reader of the results needs — profile, seed, git commit,
training steps, the validation split and its metrics (losses in the stage's unit: cross-entropy,
or rad² for the angle loss; angle errors in degrees), the stages' stops, the training time in
minutes and the SHA-256 of the weights (:mod:`histostudy.learning.checkpoints`).

A network trained on a lent GPU comes back through a narrow channel (files of at most 16 MiB):
:func:`half_precision_copy` writes its float16 copy, :func:`full_precision_copy` widens that copy
back to the float32 the networks load. The round trip rounds each weight to float16 (a relative
error of at most 2^-11); the manifests say so, and what is evaluated and shipped is the rounded
network.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from ..checkpoints import MODELS_DIR, load_checkpoint, save_checkpoint
from ._config import TrainingConfig, TrainingResult, resolve_device, stage_frames

__all__ = ["export", "full_precision_copy", "half_precision_copy"]


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


def _copy_as(weights, dest, dtype: torch.dtype, **note) -> Path:
    tensors, manifest = load_checkpoint(weights)
    for name, tensor in tensors.items():
        if (dtype == torch.float16 and tensor.is_floating_point() and tensor.numel()
                and float(tensor.abs().max()) > 65504.0):
            raise ValueError(f"weights {str(weights)!r}: tensor {name!r} exceeds float16's range (65504); "
                             "it cannot travel in half precision")
    converted = {k: (v.to(dtype) if v.is_floating_point() else v) for k, v in tensors.items()}
    kept = {k: v for k, v in manifest.items()
            if k not in ("format", "version", "config", "weights_file", "sha256", "size_bytes", "tensor_dtypes")}
    return save_checkpoint(dest, converted, manifest["config"], **{**kept, **note})


def half_precision_copy(weights, dest) -> Path:
    """Write ``weights``' checkpoint with its floating-point tensors in float16 to ``dest``
    (``<dest>.safetensors`` + ``.json``, the manifest kept, ``"float16_of"`` naming the source's
    SHA-256); returns the new manifest's path. Refuses a tensor beyond float16's range."""
    _, manifest = load_checkpoint(weights)
    return _copy_as(weights, dest, torch.float16, float16_of=manifest["sha256"])


def full_precision_copy(weights, dest) -> Path:
    """Write a float16 checkpoint (:func:`half_precision_copy`) back in float32 to ``dest``, the
    manifest kept and ``"rounded_to": "float16"`` added; returns the new manifest's path."""
    return _copy_as(weights, dest, torch.float32, rounded_to="float16")
