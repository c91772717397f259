"""A campaign's committed restart weights measured again beside its baseline, on the held-out frames
of one of its ledger's runs (or of a new seed): the comparison frame by frame that a step records,
for a run that recorded none and for any machine that has only the repository."""

from __future__ import annotations

import json
from pathlib import Path

from histostudy.core import check_count
from histostudy.learning import default_cache_dir, full_precision_copy

from ._held_out import compare_held_out, evaluate_held_out
from ._ledger import read_ledger
from ._spec import CampaignSpec

__all__ = ["compare_restart_weights"]


def compare_restart_weights(spec: CampaignSpec, *, run: int | None = None, eval_seed: int | None = None,
                            eval_frames: int | None = None, cache_dir=None, workers: int = 1) -> dict:
    """The campaign's restart weights and its baseline on the same held-out frames, frame by frame.

    The restart weights are the float16 copy of the network a step kept (``--keep``), widened to
    float32 as a restarting machine widens them; their figures may differ from the kept step's
    by that rounding.

    Args:
        spec: the campaign (:func:`~histostudy.study.campaign.load_campaign`).
        run: the ledger's run whose held-out frames (seed and count) are used; None: the run that
            kept the restart weights, else ``eval_seed``'s frames.
        eval_seed: held-out frames of this seed instead of a run's (``run`` must be None).
        eval_frames: how many frames with ``eval_seed`` (default: the campaign's).
        cache_dir: the frame cache (default: :func:`~histostudy.learning.default_cache_dir`).
        workers: processes that render missing frames.

    Returns:
        ``{"run", "seed", "frames", "restart_sha256", "baseline_weights", "candidate", "baseline",
        "paired"}``: the run used (None with ``eval_seed``), the frames, the two networks'
        :func:`evaluate_held_out` results and :func:`compare_held_out` of the two.

    Raises:
        ValueError: no committed restart weights, no baseline, ``run`` and ``eval_seed`` both given
            or neither resolvable, a run not in the ledger, or counts out of range.
    """
    if not spec.restart_weights.is_file():
        raise ValueError(f"campaign {spec.name!r} has no restart weights ({spec.restart_weights}): a step run "
                         f"with --keep writes them")
    if spec.baseline is None:
        raise ValueError(f"campaign {spec.name!r} has no baseline ([evaluation] baseline = false)")
    if run is not None and eval_seed is not None:
        raise ValueError(f"give run or eval_seed, not both (got run={run!r}, eval_seed={eval_seed!r})")
    restart_sha = json.loads(spec.restart_weights.with_suffix(".json").read_text(encoding="utf-8"))["sha256"]
    runs = read_ledger(spec.ledger_path)
    if eval_seed is None:
        if run is None:
            kept = [r for r in runs if r.get("kept_as_restart") == restart_sha]
            if not kept:
                raise ValueError(f"campaign {spec.name!r}: no ledger run kept the restart weights {restart_sha[:12]}; "
                                 f"give eval_seed")
            entry = kept[-1]
        else:
            check_count(run, "run")
            if run > len(runs):
                raise ValueError(f"run must be one of the ledger's runs 1..{len(runs)}, got {run}")
            entry = runs[run - 1]
        seed, frames, used = int(entry["held_out"]["seed"]), int(entry["held_out"]["frames"]), int(entry["run"])
    else:
        seed = check_count(eval_seed, "eval_seed", minimum=0)
        frames = check_count(spec.eval_frames if eval_frames is None else eval_frames, "eval_frames")
        used = None
    check_count(workers, "workers")
    cache_dir = default_cache_dir() if cache_dir is None else Path(cache_dir)
    widened = full_precision_copy(spec.restart_weights, cache_dir / "campaigns" / spec.name / "restart-float32")
    measure = dict(seed=seed, n_frames=frames, cache_dir=cache_dir, render=spec.eval_render, workers=workers)
    candidate = evaluate_held_out(spec.task, widened.with_suffix(".safetensors"), **measure)
    baseline = evaluate_held_out(spec.task, spec.baseline, **measure)
    return {"run": used, "seed": seed, "frames": frames, "restart_sha256": restart_sha,
            "baseline_weights": spec.baseline.name, "candidate": candidate, "baseline": baseline,
            "paired": compare_held_out(spec.task, candidate, baseline)}
