"""Network checkpoints: weights as safetensors (no pickle) beside a JSON manifest with their SHA-256,
configuration and provenance, written atomically and checked on loading (docs/training.md, "Checkpoints").
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from histostudy.core import atomic_path, atomic_write_json, git_commit, shipped_dir, to_jsonable

from .nets import build_network

__all__ = ["MODELS_DIR", "load_checkpoint", "load_network", "load_shipped", "manifest_path", "save_checkpoint",
           "sha256_file", "shipped_model", "training_summary"]

FORMAT = "histostudy.checkpoint"
VERSION = 1

#: Where the shipped weights live: ``data/models`` of a checkout, ``histostudy/_data/models`` of a wheel
#: (:func:`histostudy.core.shipped_dir`).
MODELS_DIR = shipped_dir("models")


def sha256_file(path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _weights_path(path) -> Path:
    path = Path(path)
    return path if path.suffix == ".safetensors" else path.with_name(path.name + ".safetensors")


def manifest_path(path) -> Path:
    """The manifest ``<name>.json`` of weights ``<name>.safetensors`` (or of the bare ``<name>``)."""
    return _weights_path(path).with_suffix(".json")


def _dtype_name(tensor: torch.Tensor) -> str:
    return str(tensor.dtype).removeprefix("torch.")


def _read_manifest(mpath: Path) -> dict:
    """The manifest at ``mpath`` as a dict; ``ValueError`` naming the file when it is not one."""
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"manifest {str(mpath)!r} is not readable JSON: {exc}") from None
    if not isinstance(manifest, dict):
        raise ValueError(f"manifest {str(mpath)!r} holds a JSON {type(manifest).__name__}, expected a JSON "
                         f"object ({FORMAT} manifest with format, sha256, config)")
    return manifest


def _check_tensors(tensors: dict, manifest: dict, weights: Path, mpath: Path) -> None:
    """Refuse tensors whose dtypes differ from the manifest's record, and NaN/inf values.

    A dtype relabelled in the safetensors header reinterprets the same bytes (float32 read as
    int32, say); ``load_state_dict`` would then silently cast those numbers into the network.
    """
    recorded = manifest.get("tensor_dtypes")
    if recorded is not None:
        if not isinstance(recorded, dict):
            raise ValueError(f"manifest {str(mpath)!r}: tensor_dtypes is {recorded!r}, expected an object "
                             "mapping tensor names to dtypes")
        for name in sorted(recorded.keys() | tensors.keys()):
            found = _dtype_name(tensors[name]) if name in tensors else None
            if found != recorded.get(name):
                raise ValueError(
                    f"weights {str(weights)!r}: tensor {name!r} has dtype {found or '(no such tensor)'}, but "
                    f"manifest {str(mpath)!r} records {recorded.get(name) or '(no such tensor)'}"
                )
    for name, tensor in tensors.items():
        if tensor.is_floating_point() or tensor.is_complex():
            n_bad = int((~torch.isfinite(tensor)).sum())
            if n_bad:
                raise ValueError(
                    f"weights {str(weights)!r}: tensor {name!r} holds {n_bad} non-finite value(s) (NaN or inf) "
                    f"of {tensor.numel()}; expected finite weights (a diverged training run or a damaged export)"
                )


def save_checkpoint(path, tensors: dict, config: dict, **manifest) -> Path:
    """Write ``tensors`` to ``<path>.safetensors`` and the manifest to ``<path>.json``; returns the manifest path.

    ``config`` is the network's config; keyword arguments (profile, seed, training_steps,
    validation, ...) are added to the manifest; ``git_commit`` is recorded when not given.
    """
    weights = _weights_path(path)
    if not isinstance(config, dict) or "arch" not in config:
        raise ValueError(f"config must be a network config dict with an 'arch' key, got {config!r}")
    # Before writing: weights exported into the repository (data/models) would otherwise make
    # the tree they were trained from look modified.
    commit = manifest.pop("git_commit", None) or git_commit()
    flat = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    with atomic_path(weights) as tmp:
        metadata = {"format": FORMAT, "config": json.dumps(to_jsonable(config), sort_keys=True)}
        save_file(flat, str(tmp), metadata=metadata)
    record = {"format": FORMAT, "version": VERSION, "config": config, "weights_file": weights.name,
              "sha256": sha256_file(weights), "size_bytes": weights.stat().st_size,
              "tensor_dtypes": {k: _dtype_name(v) for k, v in sorted(flat.items())}}
    record["git_commit"] = commit
    record.update(manifest)
    return atomic_write_json(manifest_path(weights), record)


def load_checkpoint(path, expected_config: dict | None = None) -> tuple[dict, dict]:
    """``(tensors, manifest)`` of a checkpoint, after checking hash and configuration.

    Raises ``ValueError`` when the manifest is missing, unreadable or not a JSON object, the
    weights' SHA-256 differs from the manifest's, the file is not valid safetensors, a tensor's
    dtype differs from the one the manifest records, a floating-point tensor holds NaN or inf, the
    header's config differs from the manifest's, or ``expected_config`` (if given) differs from the
    manifest's config.
    """
    weights = _weights_path(path)
    mpath = manifest_path(weights)
    if not weights.is_file():
        raise ValueError(f"weights file {str(weights)!r} does not exist")
    if not mpath.is_file():
        raise ValueError(f"weights {str(weights)!r} have no manifest {str(mpath)!r}")
    manifest = _read_manifest(mpath)
    if (manifest.get("format") != FORMAT or "sha256" not in manifest
            or not isinstance(manifest.get("config"), dict)):
        raise ValueError(f"manifest {str(mpath)!r} is not a {FORMAT} manifest (needs format, sha256, "
                         "config: an object)")
    digest = sha256_file(weights)
    if digest != manifest["sha256"]:
        raise ValueError(f"weights {str(weights)!r} have SHA-256 {digest}, but manifest {str(mpath)!r} "
                         f"expects {manifest['sha256']}: the file was changed or damaged")
    try:
        from safetensors import safe_open

        with safe_open(str(weights), framework="pt") as fh:
            header_config = json.loads((fh.metadata() or {}).get("config", "null"))
        tensors = load_file(str(weights))
    except (SafetensorError, OSError, ValueError) as exc:
        raise ValueError(f"weights {str(weights)!r} are not a valid safetensors file: {exc}") from None
    _check_tensors(tensors, manifest, weights, mpath)
    config = to_jsonable(manifest["config"])
    if header_config != config:
        raise ValueError(f"weights {str(weights)!r} were saved for config {header_config}, but the manifest "
                         f"says {config}")
    if expected_config is not None and to_jsonable(expected_config) != config:
        raise ValueError(f"checkpoint {str(weights)!r} has config {config}, expected {to_jsonable(expected_config)}")
    return tensors, manifest


def load_network(path, expected_config: dict | None = None) -> tuple[torch.nn.Module, dict]:
    """The network of a checkpoint, rebuilt from its config and loaded strictly, in eval mode."""
    tensors, manifest = load_checkpoint(path, expected_config)
    net = build_network(dict(manifest["config"]))
    model_tensors = {k[len("model."):]: v for k, v in tensors.items() if k.startswith("model.")}
    if not model_tensors:
        raise ValueError(f"checkpoint {str(path)!r} holds no 'model.' tensors")
    # Manifests written before tensor_dtypes (the shipped ones among them) are checked against the
    # network itself: load_state_dict would cast a relabelled tensor without a word.
    expected = net.state_dict()
    for name in sorted(model_tensors.keys() & expected.keys()):
        if model_tensors[name].dtype != expected[name].dtype:
            raise ValueError(
                f"checkpoint {str(path)!r}: tensor 'model.{name}' has dtype {_dtype_name(model_tensors[name])}, "
                f"but the network of config {manifest['config']} expects {_dtype_name(expected[name])}"
            )
    try:
        net.load_state_dict(model_tensors, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"checkpoint {str(path)!r} does not fit its config {manifest['config']}: {exc}") from None
    return net.eval(), manifest


def shipped_model(name: str, models_dir=None) -> Path | None:
    """The shipped weights of a name, where they are usable.

    Args:
        name: the weights' name (``"unet_standard"``, ``"vgg19_standard"``, ...).
        models_dir: the folder (None: ``data/models``).

    Returns:
        ``<models_dir>/<name>.safetensors`` if it and its manifest exist and the hash matches, else
        None (with a warning when present but invalid, a manifest that is no JSON object too).
    """
    folder = MODELS_DIR if models_dir is None else Path(models_dir)
    weights = folder / f"{name}.safetensors"
    if not (weights.is_file() and manifest_path(weights).is_file()):
        return None
    try:
        manifest = _read_manifest(manifest_path(weights))
        if sha256_file(weights) != manifest.get("sha256"):
            raise ValueError("SHA-256 differs from the manifest")
    except (OSError, ValueError) as exc:
        warnings.warn(f"shipped weights {os.fspath(weights)!r} are not usable ({exc}); using none", stacklevel=2)
        return None
    return weights


def load_shipped(name: str, loader, what: str):
    """``loader(path)`` of the shipped weights ``name`` (:func:`shipped_model`), or None when they are
    missing, fail their hash, or the loader rejects them (with a warning naming ``what``)."""
    path = shipped_model(name)
    if path is None:
        return None
    try:
        return loader(path)
    except (ValueError, OSError) as exc:
        warnings.warn(f"shipped {what} {os.fspath(path)!r} is not usable ({exc}); using none", stacklevel=3)
        return None


def training_summary(manifest: dict) -> str:
    """One line for a report: how a checkpoint was trained, from its manifest's training record.

    Args:
        manifest: a checkpoint manifest (``UNetRunner.manifest``, ``LearnedOrientation.manifest``).

    Returns:
        Steps and optimiser, the frames (how many, rendered from which model spacing) of the run and
        of its fine-tune stage, and the checkpoint it started from, as far as the manifest records
        them (older manifests lack some; they are left out rather than guessed).

    Raises:
        TypeError: ``manifest`` is not a dict.
    """
    if not isinstance(manifest, dict):
        raise TypeError(f"manifest must be a checkpoint manifest dict, got {type(manifest).__name__}")
    cfg = manifest.get("training_config") or {}
    parts = [f"{manifest.get('training_steps', '?')} training steps"]
    if cfg.get("optimizer"):
        parts[0] += f" ({cfg['optimizer']})"

    def frames(n, render):
        if not render:
            return f"{n} frames"
        return f"{n} frames rendered from the {render.get('render_spacing_mm', '?'):g} mm model"

    if "n_train" in cfg:
        parts.append("on " + frames(cfg["n_train"], cfg.get("render")))
    fine = cfg.get("fine_tune")
    if fine:
        parts.append("fine-tuned on " + frames(fine.get("n_train"), fine.get("render")))
    init = manifest.get("init_weights")
    if init:
        parts.append(f"started from a checkpoint of sha256 {str(init.get('sha256', '?'))[:12]}"
                     + (f" ({init['training_steps']} steps)" if init.get("training_steps") else ""))
    return ", ".join(parts)
