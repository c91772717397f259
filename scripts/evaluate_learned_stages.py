"""The learned stages on held-out frames of a seed of your choice (docs/learned-stages.md, "The
learned stages at a new seed").

- The U-Net: per class IoU, recall and precision (percent, mean over frames, as Table I), as
  shipped, with test-time flips, and the bound its input scale sets (the reference labels pooled
  to the network's scale and back).
- The orientation: the pipeline's source (the conic initialiser with the VGG19 for views without
  an ellipse) and the VGG19 alone; azimuth and elevation MAE of the nearer candidate (notebook
  03's statistics, ``study.candidate_errors``), its median and 90th percentile, and how often the
  conic fell back.
- With ``--robustness-poses N``: ``study.robustness_sweep`` over N random poses of the paper's
  range (seed ``--seed`` + 1) with these stages: how many within 2 mm, refused by the verdict, and
  accepted although 2 mm or more off; the rotation error up to the transducer's half turn.

Usage::

    python scripts/evaluate_learned_stages.py --seed 20261126 --frames 40 [--weights PATH] [--vgg19 PATH] \
        [--robustness-poses 100]

Frames: split ``eval`` of ``HybridFrames`` at ``--seed`` (the study's reference renderer, 0.125 mm
models, mixed backgrounds), cached in the frame cache. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

CLASSES = ("transducer", "outer_boundary", "inner_boundary", "gaps", "screws")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True, help="seed of the held-out frames (split 'eval')")
    parser.add_argument("--frames", type=int, default=40, help="frames (default 40)")
    parser.add_argument("--weights", default="", help="U-Net checkpoint (default: the shipped unet_standard)")
    parser.add_argument("--vgg19", default="", help="VGG19 checkpoint (default: the shipped vgg19_standard)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes (default 2)")
    parser.add_argument("--robustness-poses", type=int, default=0,
                        help="also run the robustness sweep over this many random poses (default 0: not)")
    args = parser.parse_args(argv)

    import numpy as np

    from histostudy.core import machine_summary
    from histostudy.learning import HybridFrames, RenderConfig, UNetRunner, default_cache_dir, pool_labels
    from histostudy.pose import ConicOrientation
    from histostudy.study.orientation import candidate_error_summary, candidate_errors, load_vgg19
    from histostudy.study.segmentation import evaluate_segmentation, load_unet
    from histostudy.study.stats import segmentation_metrics
    from histostudy.transducer import Feature

    print(machine_summary())
    frames = HybridFrames("eval", args.seed, RenderConfig(), cache_dir=default_cache_dir())
    frames.prerender(args.frames, workers=args.workers)
    unet, path = load_unet(args.weights)
    flips = UNetRunner(unet.network, test_time_flips=True, scale=unet.scale, manifest=unet.manifest)
    print(f"{path} ({unet.manifest['sha256'][:12]}), {args.frames} frames of split 'eval', seed {args.seed}")

    def table(segmenter) -> dict:
        per_class, _, _ = evaluate_segmentation(segmenter, (frames.frame(i) for i in range(args.frames)))
        return per_class.groupby("class")[["iou", "recall", "precision"]].mean().to_dict("index")

    k = round(1 / unet.scale)
    names = [f.name.lower() for f in Feature]
    bound_rows = []
    for i in range(args.frames):
        ref = frames.frame(i).labels
        pooled = np.repeat(np.repeat(pool_labels(ref, unet.scale), k, 0), k, 1)
        metrics = segmentation_metrics(pooled, ref, len(Feature), class_names=names)
        bound_rows.append(metrics["per_class"].set_index("class"))
    bound = {c: {m: 100.0 * float(np.nanmean([r.loc[c, m] for r in bound_rows]))
                 for m in ("iou", "recall", "precision")}
             for c in CLASSES}

    results = {"as shipped": table(unet), "test-time flips": table(flips), f"labels pooled to {unet.scale:g}": bound}
    print("| class | " + " | ".join(f"{name} IoU / recall / precision" for name in results) + " |")
    print("|---|" + "---|" * len(results))
    for c in CLASSES:
        cells = [f"{r[c]['iou']:.1f} / {r[c]['recall']:.1f} / {r[c]['precision']:.1f}" for r in results.values()]
        print(f"| {c} | " + " | ".join(cells) + " |")

    vgg, vgg_path = load_vgg19(args.vgg19)
    print(f"\norientation: {vgg_path} ({vgg.manifest['sha256'][:12]}); the conic reads {path.name}'s labels")
    sources = {"conic (pipeline)": ConicOrientation(segmenter=unet, fallback=vgg), "VGG19 alone": vgg}
    errors = candidate_errors(sources, (frames.frame(i) for i in range(args.frames)), np.random.default_rng(args.seed))
    print(candidate_error_summary(errors).to_markdown(index=False, floatfmt=".2f"))
    if args.robustness_poses > 0:
        robustness(args, unet, sources["conic (pipeline)"])
    return 0


def robustness(args, segmenter, orientation) -> None:
    """The robustness sweep with these stages (module docstring), printed."""
    import numpy as np

    from histostudy.imaging import default_biplane
    from histostudy.study.pose import robustness_summary, robustness_sweep
    from histostudy.study.pose.experiments import PoseStudyConfig
    from histostudy.transducer import TransducerModel

    seed = args.seed + 1
    table = robustness_sweep(
        args.robustness_poses, pose_model=TransducerModel.build(spacing_mm=0.47),
        render_model=TransducerModel.build(spacing_mm=0.125),
        physical=TransducerModel.build_physical(spacing_mm=0.125, rng=np.random.default_rng(seed)),
        views=default_biplane(), seed=seed, config=PoseStudyConfig(), inits=("robust",), segmenter=segmenter,
        orientation=orientation, executor=f"local:{args.workers}" if args.workers > 1 else "sequential")
    accepted = table["verdict_ok"].astype(bool)
    wrong = table[accepted & ~table["success"].astype(bool)]
    print(f"\nrobustness sweep, {args.robustness_poses} random poses, seed {seed}:")
    print(robustness_summary(table).to_markdown(index=False, floatfmt=".3f"))
    print(f"accepted 2 mm or more off: {len(wrong)} ({', '.join(f'{e:.2f}' for e in sorted(wrong['error_mm']))} mm); "
          f"rotation error up to the half turn: median {table['rotation_error_deg'].median():.2f} deg, "
          f"{int(table['half_turned'].sum())} estimates half turned")


if __name__ == "__main__":
    sys.exit(main())
