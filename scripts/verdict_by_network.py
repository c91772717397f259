"""The verdict's view-agreement figure over random poses, per U-Net: how far one view's evidence alone
moves the focal point (``PoseConfig.max_view_disagreement_mm``'s measure) for estimates within 2 mm
of the truth and for the others, then every measured estimate's verdict figures: the move, the cost
the view gains by it, and the fit (docs/campaigns.md, "Why a better U-Net was refused").

``study.pose.robustness_sweep`` over ``--poses`` random poses of the paper's range (seed ``--seed``,
the study's reference renderer and 0.125 mm models, initialisation "robust"), every network on the
same frames, each driving the conic orientation initialiser with the shipped VGG19 as its fallback.

Usage::

    python scripts/verdict_by_network.py --poses 20 --seed 4242 --weights /tmp/candidate.safetensors
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=20, help="random poses (default 20)")
    parser.add_argument("--seed", type=int, default=4242, help="the sweep's seed (default 4242)")
    parser.add_argument("--weights", action="append", default=[],
                        help="a U-Net checkpoint to compare with the shipped one (repeatable)")
    parser.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    args = parser.parse_args(argv)

    import numpy as np
    import pandas as pd

    from histostudy.core import machine_summary
    from histostudy.imaging import default_biplane
    from histostudy.learning import UNetRunner, default_segmenter, default_vgg19
    from histostudy.pose import ConicOrientation
    from histostudy.study.pose import robustness_sweep
    from histostudy.study.pose.experiments import PoseStudyConfig
    from histostudy.transducer import TransducerModel

    print(machine_summary())
    networks = {"shipped": default_segmenter(), **{Path(w).name: UNetRunner.load(w) for w in args.weights}}
    vgg19 = default_vgg19()
    sets = {name: dict(segmenter=unet, orientation=ConicOrientation(segmenter=unet, fallback=vgg19), inits=("robust",))
            for name, unet in networks.items()}
    table = robustness_sweep(
        args.poses, pose_model=TransducerModel.build(spacing_mm=0.47),
        render_model=TransducerModel.build(spacing_mm=0.125),
        physical=TransducerModel.build_physical(spacing_mm=0.125, rng=np.random.default_rng(args.seed)),
        views=default_biplane(), seed=args.seed, config=PoseStudyConfig(), stage_sets=sets,
        executor=f"local:{args.workers}" if args.workers > 1 else "sequential")
    views = [c for c in table.columns if c.startswith("disagreement_mm_")]
    table["disagreement_mm"] = table[views].max(axis=1)  # the larger of the two views'
    rows = []
    for name in networks:
        rows_of = table[table["stages"] == name]
        correct, off = rows_of[rows_of["error_mm"] < 2.0], rows_of[~(rows_of["error_mm"] < 2.0)]
        d = correct["disagreement_mm"].dropna()
        rows.append({"U-Net": name, "poses": len(rows_of), "within 2 mm": len(correct),
                     "accepted": int(rows_of["verdict_ok"].sum()),
                     "accepted 2 mm or more off": int((off["verdict_ok"].astype(bool)).sum()),
                     "within 2 mm: disagreement median / p90 / max (mm)":
                         f"{d.median():.2f} / {d.quantile(0.9):.2f} / {d.max():.2f}" if len(d) else "—",
                     "off: error (mm), disagreement (mm)": "; ".join(
                         f"{e:.1f}, {x:.2f}" for e, x in zip(off["error_mm"], off["disagreement_mm"])) or "—"})
    print(pd.DataFrame(rows).to_markdown(index=False))
    # Per estimate whose views' agreement was measured: each view's move, and what it gains by it.
    gains = [c for c in table.columns if c.startswith("relative_gain_")]
    table["relative_gain"] = table[gains].max(axis=1)
    table["gain_px2"] = table[[c for c in table.columns if c.startswith("gain_px2_")]].max(axis=1)
    measured = table.dropna(subset=["disagreement_mm"])
    print("\n" + measured[["stages", "pose", "error_mm", "verdict_ok", "disagreement_mm", "gain_px2", "relative_gain",
                           *[c for c in table.columns if c.startswith(("rms_", "body_rms_", "unexplained_"))]]]
          .sort_values(["stages", "error_mm"]).to_markdown(index=False, floatfmt=".3f"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
