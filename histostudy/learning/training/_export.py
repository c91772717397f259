"""Exporting a trained network to ``data/models`` with its manifest, and the float16 round trip of a
network trained on a lent GPU (docs/training.md, "The training package").
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
    """Copy the run's best network to ``<models_dir>/<name>.safetensors`` with the full manifest
    (profile, seed, git commit, steps, validation split and metrics, stops, minutes, SHA-256).

    Args:
        result: the run's :class:`~histostudy.learning.training._config.TrainingResult`.
        cfg: the run's :class:`~histostudy.learning.training._config.TrainingConfig`.
        name: the weights' name (:func:`~histostudy.learning.training._config.export_name`).
        seed: the profile's seed the run drew its frames from.
        profile: the profile's name.
        models_dir: the folder (None: ``data/models``).

    Returns:
        The path of the manifest written.

    Raises:
        ValueError: the run's best checkpoint fails its checks.
        OSError: the run's files cannot be read or the copy cannot be written.
    """
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
    """A checkpoint's float16 copy, for the narrow channel back from a lent GPU (docs/training.md).

    Args:
        weights: the checkpoint's ``.safetensors``.
        dest: the copy's path without suffix (``<dest>.safetensors`` and ``.json`` are written).

    Returns:
        The new manifest's path (the manifest kept, ``"float16_of"`` naming the source's SHA-256).

    Raises:
        ValueError: the checkpoint fails its checks, or a tensor exceeds float16's range (65504).
    """
    _, manifest = load_checkpoint(weights)
    return _copy_as(weights, dest, torch.float16, float16_of=manifest["sha256"])


def full_precision_copy(weights, dest) -> Path:
    """A float16 checkpoint (:func:`half_precision_copy`) widened back to the float32 the networks load.

    Args:
        weights: the float16 checkpoint's ``.safetensors``.
        dest: the copy's path without suffix.

    Returns:
        The new manifest's path (the manifest kept, ``"rounded_to": "float16"`` added).

    Raises:
        ValueError: the checkpoint fails its checks.
    """
    return _copy_as(weights, dest, torch.float32, rounded_to="float16")
