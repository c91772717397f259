"""Warm starts that hold (docs/tracking.md, "Warm starts that hold"): the fast tracker in turn on a
stretch of the moving cine (no receiver, no drops beyond ``--stride``), and the verdict's view
agreement of the true pose measured on the tracking region's label grid and on the full frames.

1. ``--statistic``: for each frame, the true pose's view disagreement (the larger of the two views,
   mm; :func:`histostudy.pose.verdict.view_disagreement_mm`, the statistic of
   :func:`histostudy.pose.estimate_pose`'s ``max_view_disagreement_mm``) on the region at label
   scale 0.5 (the fast warm path's grid), on the region at scale 1 (the second attempt's) and on the
   full frames (``estimate_pose``'s own grid), each with ``--draws`` draws of its 1500-point subset.
2. The frames ``--start``, ``--start + --stride``, ... through ``Tracker(fast=...).update`` for each
   variant: ``before`` (``rescue_scale=None, resume_refused=False``), ``rescue`` (the second attempt
   only) and ``default``. Counts, seconds per warm update and in all, focal error of accepted poses.

The from-scratch estimates run on the full frames (``scratch_label_scale=1`` where that option
exists) so that only the warm starts differ. Usage (the cine of bench_moving_cine.py)::

    .venv/bin/python benchmarks/bench_warm_starts.py --folder /tmp/mc60/cine --start 150 --frames 26
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass

import numpy as np

from histostudy.imaging import View, load_frame, load_views
from histostudy.pose import PoseCost, RegionEstimator, Tracker, TrackingConfig
from histostudy.pose.distance_maps import DistanceMaps
from histostudy.pose.verdict import view_disagreement_mm
from histostudy.study.your_data.moving_cine import load_moving_cine
from histostudy.transducer import TransducerModel


@dataclass(frozen=True)
class _Viewed:
    """What view_disagreement_mm reads of a frame: its view (here a region's)."""

    view: View


def disagreement(maps, views, model, T, scale, seed, opts) -> float:
    """The larger view's disagreement (mm) of pose ``T`` on ``maps`` (one per view, at ``scale``)."""
    cost = PoseCost(model.points, maps, outside_distance_px=opts.outside_distance_px * scale)
    consistency = cost.subset(opts.init_points_per_class, np.random.default_rng(seed)).capped(
        opts.refine_truncation_px * scale)
    return max(view_disagreement_mm(consistency, [_Viewed(v) for v in views], T, model.focal_point_mm).values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", required=True, help="the moving cine's folder (bench_moving_cine.py)")
    parser.add_argument("--start", type=int, default=150, help="first frame (default 150)")
    parser.add_argument("--frames", type=int, default=26, help="frames tracked (default 26)")
    parser.add_argument("--stride", type=int, default=1, help="every n-th frame (default 1)")
    parser.add_argument("--draws", type=int, default=4, help="subset draws of the statistic (default 4)")
    parser.add_argument("--statistic", action="store_true", help="measure the true pose's statistic first")
    args = parser.parse_args()
    cine = load_moving_cine(args.folder)
    truth, views = cine.read_truth(), load_views(cine.views)
    model = TransducerModel.build(spacing_mm=0.47)
    ks = list(range(args.start, args.start + args.frames * args.stride, args.stride))
    pairs = [[load_frame(p, v, line_integrals=False) for p, v in zip(cine.frames[k], views)] for k in ks]
    extra = {"scratch_label_scale": 1.0} if "scratch_label_scale" in TrackingConfig.field_names() else {}
    print(f"frames {ks[0]}..{ks[-1]} stride {args.stride}; load average {os.getloadavg()}", flush=True)

    if args.statistic:
        probe = Tracker(model, views, rng=0, fast=TrackingConfig(**extra))
        opts, seeds = probe.options, range(args.draws)
        grids = {s: RegionEstimator(model, views, probe.segmenter, opts, TrackingConfig(label_scale=s),
                                    np.random.default_rng(0)) for s in (0.5, 1.0)}
        full = grids[0.5].full_frame_segmenter  # UNetRunner.segment: estimate_pose's labels
        values = {"region 0.5": [], "region 1": [], "full frames": []}
        for k, frames in zip(ks, pairs):
            T = truth["T_carm_transducer"][k]
            for s, name in ((0.5, "region 0.5"), (1.0, "region 1")):
                prepared = grids[s].prepare(frames, T, None)
                values[name] += [disagreement(prepared.maps, [r.view for r in prepared.regions], model, T, s, d, opts)
                                 for d in seeds]
            maps = [DistanceMaps(f.view, full.segment(f), occlusion_aware=True) for f in frames]
            values["full frames"] += [disagreement(maps, views, model, T, 1.0, d, opts) for d in seeds]
        limit = opts.max_view_disagreement_mm
        for name, v in values.items():
            v = np.array(v)
            print(f"true pose, {name}: view disagreement mean {v.mean():.2f} mm, median {np.median(v):.2f}, "
                  f"over the {limit} mm limit {100 * np.mean(v > limit):.0f} % of {len(v)}", flush=True)

    variants = {"before": dict(rescue_scale=None, resume_refused=False), "rescue": dict(resume_refused=False),
                "default": {}}
    for name, options in variants.items():
        tracker = Tracker(model, views, rng=0, fast=TrackingConfig(**options, **extra))
        errors, warm_s, t0 = [], [], time.perf_counter()
        for k, frames in zip(ks, pairs):
            t = time.perf_counter()
            result = tracker.update([f.image for f in frames])
            if tracker.last_kind == "warm":
                warm_s.append(time.perf_counter() - t)
            if result.verdict.ok:
                errors.append(np.linalg.norm(result.T_carm_transducer[:3, 3] - truth["T_carm_transducer"][k][:3, 3]))
        s = tracker.stats()
        print(f"{name}: warm {s['n_warm']} (second attempts held {s['n_rescued']}/{s['n_rescue_attempts']}, from a "
              f"refused pose {s['n_resumed']}/{s['n_resume_attempts']}), lost {s['n_lost']}, re-acquired "
              f"{s['n_reacquired']}, from scratch {s['n_from_scratch']}, accepted {s['n_accepted']}/{s['n_updates']}; "
              f"warm update median {np.median(warm_s) if warm_s else float('nan'):.3f} s; "
              f"{time.perf_counter() - t0:.1f} s in all; focal error mean {np.mean(errors):.2f} mm, "
              f"largest {np.max(errors):.2f} mm; load average {os.getloadavg()}", flush=True)


if __name__ == "__main__":
    main()
