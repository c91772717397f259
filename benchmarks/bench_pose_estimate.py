"""Time per stage of ``estimate_pose`` (§II-B.3-4): the paper's mode, the fast mode and warm-start
tracking, on the same synthetic biplane frames.

Baseline: the paper's mode (robust initialisation + Nelder-Mead), measured in the same run; the
fast mode (same initialisation + Levenberg-Marquardt) and tracking (a warm start from a pose
1 mm / 0.3 deg off, no initialisation) are printed as ratios against it. Frames: the physical
transducer (0.25 mm render model) on a phantom scene with Poisson noise; segmentation: the oracle
degraded to Table I, whose own cost (drawing the errors) is printed but is not what a U-Net costs.

Run: ``python benchmarks/bench_pose_estimate.py [--poses 3] [--repeat 2]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from histostudy.imaging import default_biplane, random_background, render_frame
from histostudy.learning import OracleOrientation, OracleSegmenter
from histostudy.pose import apply_left_perturbation, estimate_pose
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.study.pose.geometry import experiment_pose
from histostudy.transducer import TransducerModel

STAGES = ("segmentation", "distance_maps", "orientation", "initialisation", "refinement", "verdict", "total")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()

    views = default_biplane()
    model = TransducerModel.build(spacing_mm=0.47)
    render_model = TransducerModel.build(spacing_mm=0.25)
    physical = TransducerModel.build_physical(spacing_mm=0.25, rng=np.random.default_rng(1))
    config = PoseStudyConfig()
    segmenter = config.segmenter()
    # Compile the numba kernels before timing anything.
    warm = [render_frame(model, experiment_pose(np.random.default_rng(0), config, np.zeros(3)), v,
                         rng=np.random.default_rng(0), n_splats=1) for v in views]
    estimate_pose(warm, model, segmenter=OracleSegmenter(), orientation=OracleOrientation(), mode="fast",
                  raise_on_failure=False)

    times = {name: {s: [] for s in STAGES} for name in ("paper", "fast", "track")}
    errors = {name: [] for name in times}
    for p in range(args.poses):
        rng = np.random.default_rng(100 + p)
        scene = random_background(rng, "phantom")
        T = experiment_pose(rng, config, scene.meta.get("phantom_center_mm", np.zeros(3)))
        frames = [render_frame(render_model, T, v, rng=rng, physical=physical, background=scene) for v in views]
        truth = T[:3, :3] @ physical.focal_point_mm + T[:3, 3]
        start = apply_left_perturbation(T, np.r_[np.deg2rad([0.2, -0.2, 0.1]), [0.6, -0.6, 0.5]])
        for r in range(args.repeat):
            for name, kwargs in (("paper", dict(mode="paper")), ("fast", dict(mode="fast")),
                                 ("track", dict(mode="fast", initial_pose=start))):
                res = estimate_pose(frames, model, segmenter=segmenter, orientation=OracleOrientation(),
                                    rng=np.random.default_rng(r),
                                    raise_on_failure=False, **kwargs)
                for s in STAGES:
                    times[name][s].append(res.timings_s.get(s, 0.0))
                errors[name].append(np.linalg.norm(res.focal_point_mm - truth) if res.verdict.ok else np.nan)

    n = args.poses * args.repeat
    print(f"estimate_pose on {args.poses} biplane pairs x {args.repeat} repeats (median seconds per stage)")
    print(f"{'stage':16s}" + "".join(f"{name:>12s}" for name in times))
    for s in STAGES:
        print(f"{s:16s}" + "".join(f"{np.median(times[name][s]):12.3f}" for name in times))
    base = np.median(times["paper"]["initialisation"]) + np.median(times["paper"]["refinement"])
    for name in times:
        pose_s = np.median(times[name]["initialisation"]) + np.median(times[name]["refinement"])
        err = np.asarray(errors[name])
        print(f"{name:6s}: init + refine {pose_s:.3f} s = {pose_s / base:.2f} x the paper mode; "
              f"focal error {np.nanmean(err):.3f} mm mean, {int(np.isnan(err).sum())}/{n} failed verdicts")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"(benchmark wall time {time.perf_counter() - t0:.0f} s)")
