"""The prepared GPU run of the learned stages (docs/training.md, "On a lent GPU").

On a lent machine (16 cores, one H100-class GPU), from the repository's root, in one command::

    mkdir -p $OUT && PYTHONUNBUFFERED=1 python3 scripts/gpu_training_run.py --out $OUT --eval-seed N \\
        2>&1 | tee $OUT/log.txt

It runs, against a wall-time budget (``--minutes``, default 9):

1. the frames of every table (``--tables``, default the standard profile's ``segmentation_gpu`` and
   ``orientation_gpu``) rendered into the frame cache in ``--render-workers`` processes, the
   transducer splatted on the GPU (the tables' ``render.splat_device = "auto"``);
2. each table trained on CUDA (``histostudy.learning.train``), its ``max_minutes`` scaled so that
   the tables share what the rendering left, less a reserve for step 3;
3. each network exported, rounded to float16 (``half_precision_copy``: the files come back through
   at most 8 files of 16 MiB) and, widened again, evaluated beside the shipped one of its task on
   ``--eval-frames`` held-out frames of seed ``--eval-seed`` (the study's reference renderer): per
   class IoU and recall for a U-Net, azimuth / elevation MAE and the direction error for a VGG19.

``$OUT`` then holds ``<name>.safetensors`` + ``<name>.json`` per network, ``run.json`` (machine,
commit, timings, the training results and the evaluation) and the log. The weights are not
shipped by this script: back on the development machine, widen them (``full_precision_copy``)
and ship them only if they beat the shipped ones there as well (held-out frames and the
robustness sweep, docs/training.md).

``--toy`` shrinks everything (a few frames of a small detector, one epoch) so that the whole run is
tested on a CPU in CI (tests/scripts/test_gpu_training_run.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))  # the lent machine runs a copy of the working tree, not an installed package

#: Weights files come back through at most this many bytes each (the device tool's limit).
MAX_FILE_BYTES = 16 * 2**20

#: Minutes kept for the export and the evaluation after the training.
RESERVE_MINUTES = 1.0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the weights, run.json (and the log)")
    parser.add_argument("--eval-seed", type=int, required=True,
                        help="seed of the held-out evaluation frames: one the project has not used before")
    parser.add_argument("--profile", default="standard", help="profile holding the tables (default: standard)")
    parser.add_argument("--tables", nargs="+", default=["segmentation_gpu", "orientation_gpu"],
                        help="training tables to run, in order (default: segmentation_gpu orientation_gpu)")
    parser.add_argument("--minutes", type=float, default=9.0, help="wall-time budget of the whole run (default 9)")
    parser.add_argument("--render-workers", type=int, default=os.cpu_count() or 1,
                        help="rendering processes (default: every core)")
    parser.add_argument("--eval-frames", type=int, default=60, help="held-out frames per network (default 60)")
    parser.add_argument("--cache-dir", default=None, help="frame cache (default: histostudy's, $HISTOSTUDY_CACHE)")
    parser.add_argument("--toy", action="store_true", help="a few frames of a small detector, one epoch: a CPU test")
    return parser


def _toy(cfg):
    """``cfg`` shrunk to a CPU test's size: the same stages and code, a few small frames."""
    render = dataclasses.replace(cfg.render, render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))
    return dataclasses.replace(cfg, render=render, n_train=4, n_val=2, batch_size=2, max_epochs=1,
                               crop=None if cfg.crop is None else 64, crops_per_frame=1, max_minutes=None)


def _half_bytes(cfg) -> int:
    from histostudy.learning import build_network

    return 2 * sum(p.numel() for p in build_network(cfg.network).parameters())


def _evaluate(task: str, weights: Path, frames, n: int) -> dict:
    """The held-out figures of ``weights`` and of the shipped network of ``task`` on the same frames."""
    import numpy as np

    from histostudy.learning import LearnedOrientation, UNetRunner, shipped_model
    from histostudy.study.orientation import direction_error_summary, evaluate_orientation
    from histostudy.study.segmentation import evaluate_segmentation

    shipped = shipped_model("unet_standard" if task == "segmentation" else "vgg19_standard")
    out = {}
    for label, path in (("trained", weights), ("shipped", shipped)):
        if path is None:
            continue
        if task == "segmentation":
            per_class, per_image, _ = evaluate_segmentation(UNetRunner.load(path), (frames.frame(i) for i in range(n)))
            table = per_class.groupby("class")[["iou", "recall", "precision"]].mean()
            out[label] = {"per_class_percent": {c: {k: (None if np.isnan(v) else float(v)) for k, v in row.items()}
                                                for c, row in table.iterrows()},
                          "global_accuracy_percent": float(per_image["global_accuracy"].mean())}
        else:
            rows = evaluate_orientation(LearnedOrientation.load(path), (frames.frame(i) for i in range(n)),
                                        np.random.default_rng(0))
            out[label] = {"azimuth_mae_deg": float(rows["azimuth_error_deg"].abs().mean()),
                          "elevation_mae_deg": float(rows["elevation_error_deg"].abs().mean()),
                          "direction": direction_error_summary(rows)}
        out[label]["weights"] = str(path)
    return out


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    t_start = time.monotonic()
    minutes_used = lambda: (time.monotonic() - t_start) / 60.0  # noqa: E731

    import numpy as np
    import torch

    from histostudy.core import git_commit, machine_summary
    from histostudy.learning import (
        TRAINING_TABLES,
        HybridFrames,
        RenderConfig,
        TrainingConfig,
        default_cache_dir,
        export,
        export_name,
        full_precision_copy,
        half_precision_copy,
        prerender_run,
        train,
    )
    from histostudy.reporting import load_profile

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(args.cache_dir) if args.cache_dir else default_cache_dir()
    device = "cuda" if torch.cuda.is_available() else "cpu"
    print(machine_summary())
    print(f"torch {torch.__version__}, device {device}"
          + (f" ({torch.cuda.get_device_name()})" if device == "cuda" else "") + f", commit {git_commit()}")
    if device == "cpu" and not args.toy:
        print("gpu_training_run: torch sees no CUDA device; run it on a GPU machine (or --toy on a CPU)",
              file=sys.stderr)
        return 2

    profile = load_profile(args.profile)
    configs = {}
    for name in args.tables:
        if name not in TRAINING_TABLES or name not in profile.training:
            print(f"gpu_training_run: profile {profile.name!r} has no [training.{name}] table", file=sys.stderr)
            return 2
        cfg = TrainingConfig.from_table(TRAINING_TABLES[name][0], profile.training[name])
        cfg = _toy(cfg) if args.toy else cfg
        if cfg.init_weights and not Path(cfg.init_weights).is_absolute():
            # a profile's paths are the repository's, wherever the run was started
            cfg = dataclasses.replace(cfg, init_weights=str(REPO / cfg.init_weights))
        if _half_bytes(cfg) > MAX_FILE_BYTES:
            print(f"gpu_training_run: [training.{name}]'s network is {_half_bytes(cfg) / 2**20:.1f} MiB in float16, "
                  f"more than a {MAX_FILE_BYTES // 2**20} MiB file can bring back", file=sys.stderr)
            return 2
        configs[name] = cfg

    record = {"commit": git_commit(), "machine": machine_summary(), "device": device, "profile": profile.name,
              "seed": profile.seed, "eval_seed": args.eval_seed, "toy": args.toy, "budget_minutes": args.minutes,
              "tables": {}}

    # 1. render every table's frames first: the training budgets are then known
    for name, cfg in configs.items():
        t0 = time.monotonic()
        rendered = prerender_run(cfg, profile.seed, cache_dir=cache, workers=args.render_workers)
        seconds = time.monotonic() - t0
        record["tables"][name] = {"frames_rendered": rendered, "render_seconds": round(seconds, 1),
                                  "frames_per_second": round(rendered / seconds, 2) if rendered else None}
        print(f"{name}: rendered {rendered} frames in {seconds:.0f} s ({args.render_workers} processes)")

    # 2. train, the tables sharing what is left in proportion to their own budgets
    left = args.minutes - minutes_used() - RESERVE_MINUTES
    asked = {n: (c.max_minutes or 1.0) for n, c in configs.items()}
    for name, cfg in configs.items():
        if not args.toy:
            share = max(0.5, left * asked[name] / sum(asked.values()))
            cfg = dataclasses.replace(cfg, max_minutes=share)
        t0 = time.monotonic()
        result = train(cfg, cache / "runs" / f"{name}-{profile.name}-gpu", seed=profile.seed, profile=profile.name,
                       resume=False, progress=False, cache_dir=cache)
        export_to = export(result, cfg, export_name(name, cfg.network["arch"], profile.name), seed=profile.seed,
                           profile=profile.name, models_dir=cache / "exported")
        half = half_precision_copy(export_to.with_suffix(".safetensors"), out / export_to.stem)
        widened = full_precision_copy(half.with_suffix(".safetensors"), cache / "widened" / export_to.stem)
        record["tables"][name].update(
            train_minutes=round((time.monotonic() - t0) / 60.0, 2), max_minutes=cfg.max_minutes, steps=result.steps,
            epochs=result.epochs, stopped=result.stopped, validation=result.validation,
            weights=half.with_suffix(".safetensors").name,
            weights_bytes=half.with_suffix(".safetensors").stat().st_size)
        print(f"{name}: {result.steps} steps, stopped {result.stopped}; best validation {result.validation}")
        configs[name] = (cfg, widened.with_suffix(".safetensors"))

    # 3. held-out evaluation of the rounded networks beside the shipped ones, on frames as notebooks
    #    02 and 03 render them (the reference renderer, 0.125 mm models, mixed backgrounds)
    for name, (cfg, weights) in configs.items():
        render = RenderConfig(detector=cfg.render.detector)
        if args.toy:
            render = dataclasses.replace(render, render_spacing_mm=0.47, label_spacing_mm=0.47)
        n = max(1, min(args.eval_frames, 2) if args.toy else args.eval_frames)
        frames = HybridFrames("eval", args.eval_seed, render, cache_dir=cache)
        frames.prerender(n, workers=args.render_workers)
        record["tables"][name]["evaluation"] = _evaluate(cfg.task, weights, frames, n)
        record["tables"][name]["evaluation"]["frames"] = f"{n} frames of split 'eval', seed {args.eval_seed}"
        print(f"{name}: held out {json.dumps(record['tables'][name]['evaluation'], default=str)}")

    record["wall_minutes"] = round(minutes_used(), 2)
    (out / "run.json").write_text(json.dumps(record, indent=1, default=lambda v: v.item() if isinstance(v, np.generic)
                                             else str(v)) + "\n", encoding="utf-8")
    print(f"done in {record['wall_minutes']} min; {out}/run.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
