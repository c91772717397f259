"""One step of a campaign: train on from where the campaign stands on this machine (its checkpoint in
the cache, else its committed restart weights, else from the start) for a number of minutes, measure
the network on held-out frames of a seed drawn after the training, beside the baseline network on the
same frames, and add the step to the ledger."""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from histostudy.core import check_count, check_positive, cpu_seconds, git_commit
from histostudy.core.machine import cpu_model, isa_flags
from histostudy.core.provenance import REPO_ROOT
from histostudy.learning import (
    TrainingConfig,
    default_cache_dir,
    export,
    full_precision_copy,
    half_precision_copy,
    prerender_run,
    shipped_model,
    train,
)

from ._held_out import compare_held_out, evaluate_held_out
from ._ledger import append_entry
from ._spec import CampaignSpec

__all__ = ["campaign_run_dir", "run_campaign_step"]


def campaign_run_dir(spec: CampaignSpec, cache_dir=None) -> Path:
    """Where this machine keeps the campaign's training run.

    Args:
        spec: the campaign.
        cache_dir: the machine's cache folder (default: :func:`~histostudy.learning.default_cache_dir`).

    Returns:
        ``<cache>/campaigns/<name>/run`` (not created here).
    """
    return (default_cache_dir() if cache_dir is None else Path(cache_dir)) / "campaigns" / spec.name / "run"


def _starting_point(spec: CampaignSpec, run_dir: Path, log) -> tuple[str, TrainingConfig, float, int]:
    """``(start, config, elapsed_s, steps)``: how this step starts (``"resumed"``, ``"restart from
    committed weights"`` or ``"fresh"``), the training configuration it resumes or starts, and the
    seconds and steps the run had trained before."""
    cfg = spec.training
    state_path = run_dir / "state.json"
    if state_path.is_file():
        previous = json.loads(state_path.read_text())
        cfg = dataclasses.replace(cfg, init_weights=previous["config"].get("init_weights"),
                                  classification_epochs=previous["config"].get("classification_epochs", 0))
        return "resumed", cfg, float(previous["state"].get("elapsed_s", 0.0)), int(previous["state"]["steps"])
    if spec.restart_weights.is_file():
        widened = full_precision_copy(spec.restart_weights, run_dir.parent / "restart-float32")
        log(f"{spec.name}: no run on this machine; restarting from the committed weights {spec.restart_weights}")
        # the restart weights are a finished network: an orientation run goes on with its regressor
        cfg = dataclasses.replace(cfg, init_weights=str(widened.with_suffix(".safetensors")), classification_epochs=0)
        return "restart from committed weights", cfg, 0.0, 0
    return "fresh", cfg, 0.0, 0


def run_campaign_step(spec: CampaignSpec, minutes: float, *, eval_seed: int, cache_dir=None,
                      eval_frames: int | None = None, render_workers: int = 1, keep: bool = False,
                      progress: bool = False, log: Callable[[str], None] = print) -> dict:
    """Train the campaign ``minutes`` more, measure it on held-out frames and record the step.

    The run goes on from its checkpoint in this machine's cache (optimiser and schedule included);
    where the cache has none, from the campaign's committed float16 restart weights (a new run warm-
    started from them: optimiser state and schedule start again); else from the start. Frames are
    the cache's, rendered once per content (``render_workers`` processes render the missing ones
    first). The ledger counts the CPU time of this process and its rendering processes. The
    campaign's baseline (the shipped network, unless its ``[evaluation] baseline`` says otherwise) is
    measured on the same held-out frames, and the two compared frame by frame
    (:func:`compare_held_out`): the entry's ``baseline`` and ``paired``.

    Args:
        spec: the campaign (:func:`~histostudy.study.campaign.load_campaign`).
        minutes: training minutes of this step (wall; the rendering of missing frames beforehand
            is not counted in them but is in the step's CPU-hours).
        eval_seed: the held-out frames' seed: drawn after the training changed (the CLI draws it
            from the operating system's entropy and the ledger records it).
        cache_dir: frame cache and run folder (default: :func:`~histostudy.learning.default_cache_dir`).
        eval_frames: held-out frames (default: the campaign's).
        render_workers: processes that render missing training and held-out frames.
        keep: also write the network as the campaign's float16 restart weights
            (``<campaign>/restart.safetensors``, to commit): the next machine restarts from them.
        progress: show the epochs' progress bars.
        log: where progress lines go.

    Returns:
        The ledger entry written (``ledger.json``'s new run).

    Raises:
        ValueError: ``minutes``, ``eval_seed``, ``eval_frames`` or ``render_workers`` out of range;
            ``minutes`` ended before the campaign's first epoch; a run folder whose run was started
            from another definition of the campaign.
        BlockingIOError: another step of this campaign is running on this machine.
    """
    check_positive(minutes, "minutes")
    check_count(eval_seed, "eval_seed", minimum=0)
    eval_frames = check_count(spec.eval_frames if eval_frames is None else eval_frames, "eval_frames")
    check_count(render_workers, "render_workers")
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    run_dir = campaign_run_dir(spec, cache_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir.parent / "lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise BlockingIOError(f"campaign {spec.name!r}: another step is running on this machine "
                                  f"(lock {run_dir.parent / 'lock'})") from None
        return _step(spec, float(minutes), int(eval_seed), cache_dir, run_dir, eval_frames, render_workers,
                     keep, progress, log)


def _step(spec, minutes, eval_seed, cache_dir, run_dir, eval_frames, render_workers, keep, progress, log) -> dict:
    started = datetime.now(UTC)
    start, cfg, elapsed_s, steps_before = _starting_point(spec, run_dir, log)
    cfg = dataclasses.replace(cfg, max_minutes=elapsed_s / 60.0 + minutes)
    t0, cpu0 = time.monotonic(), cpu_seconds()
    # a run without the cache renders each epoch's frames anew in its own loop: none to count here
    rendered = prerender_run(cfg, spec.seed, cache_dir=cache_dir, workers=render_workers) if cfg.cache else 0
    try:
        result = train(cfg, run_dir, seed=spec.seed, profile=f"campaign {spec.name}", resume=True,
                       progress=progress, log=log, cache_dir=cache_dir)
    except ValueError as exc:
        if "another configuration or seed" not in str(exc):
            raise
        raise ValueError(f"campaign {spec.name!r}: its definition ({spec.folder / 'campaign.toml'}) changed since "
                         f"the run in {run_dir} started; a changed campaign is a new one (copy it under a new "
                         f"name), or delete {run_dir} to restart this one from its committed weights") from None
    if not result.best.is_file():
        raise ValueError(f"minutes {minutes:g} ended before the campaign's first epoch did (nothing to measure "
                         f"or record); give the step more minutes")
    manifest_file = export(result, cfg, "candidate", seed=spec.seed, profile=f"campaign {spec.name}",
                           models_dir=run_dir.parent)
    candidate, manifest = manifest_file.with_suffix(".safetensors"), json.loads(manifest_file.read_text())
    t_train, cpu_train = time.monotonic() - t0, cpu_seconds() - cpu0
    held_out = evaluate_held_out(spec.task, candidate, seed=eval_seed, n_frames=eval_frames, cache_dir=cache_dir,
                                 render=spec.eval_render, workers=render_workers)
    baseline = _usable_baseline(spec, log)
    compared = {}
    if baseline is not None:
        baseline_held = evaluate_held_out(spec.task, baseline, seed=eval_seed, n_frames=eval_frames,
                                          cache_dir=cache_dir, render=spec.eval_render, workers=render_workers)
        compared = {"baseline": {"weights": _shown(baseline), "sha256": _sha256_of(baseline),
                                 "held_out": baseline_held},
                    "paired": compare_held_out(spec.task, held_out, baseline_held)}
    cpu_eval = cpu_seconds() - cpu0 - cpu_train
    entry = {
        "started_utc": started.isoformat(timespec="seconds"),
        "finished_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "git_commit": git_commit(),
        "machine": {"cpu_model": cpu_model(), "cores": os.cpu_count(), "isa": isa_flags(),
                    "device": manifest.get("device", "cpu"), "threads": cfg.threads},
        "start": start, "init_weights": (manifest.get("init_weights") or {}).get("sha256"),
        "minutes_asked": minutes, "wall_minutes": t_train / 60.0, "cpu_hours": cpu_train / 3600.0,
        "eval_cpu_hours": cpu_eval / 3600.0, "frames_rendered": rendered, "n_train": cfg.n_train, "n_val": cfg.n_val,
        "steps_before": steps_before, "steps_after": result.steps, "epochs_total": len(result.history),
        "stopped": result.stopped, "validation": result.validation, "held_out": held_out,
        "weights_sha256": manifest["sha256"], **compared,
    }
    if keep:
        restart = half_precision_copy(candidate, spec.folder / "restart")
        entry["kept_as_restart"] = json.loads(restart.read_text())["sha256"]
        log(f"{spec.name}: restart weights written to {restart.with_suffix('.safetensors')} (float16; commit them)")
    return append_entry(spec.ledger_path, spec.name, entry)


def _usable_baseline(spec: CampaignSpec, log) -> Path | None:
    """The campaign's baseline weights where they exist and match their manifest's hash, else None
    (said in the log: the step is then recorded without a comparison)."""
    if spec.baseline is None:
        return None
    weights = shipped_model(spec.baseline.stem, spec.baseline.parent)
    if weights is None:
        log(f"{spec.name}: the baseline {spec.baseline} is missing or fails its manifest's hash; "
            f"this step is recorded without a comparison")
    return weights


def _sha256_of(weights: Path) -> str:
    return json.loads(weights.with_suffix(".json").read_text(encoding="utf-8"))["sha256"]


def _shown(path: Path) -> str:
    """``path`` from the repository root where it lies inside it (a ledger is committed: no machine's
    folders in it), else its name."""
    try:
        return path.resolve().relative_to(REPO_ROOT.resolve()).as_posix()
    except ValueError:
        return path.name
