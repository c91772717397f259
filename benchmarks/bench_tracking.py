"""Live tracking speed (§II-A, §II-B.2-3; docs/tracking.md): warm-started ``Tracker`` updates with
the learned stages, segmentation included, on a synthetic moving cine.

Baseline, measured in the same run: the full-frame path, ``Tracker(model, views, fast=False, mode=...)``
(every warm update is ``estimate_pose`` from the last pose on the full frames; ``--baseline-mode``,
default ``fast``: the same Levenberg-Marquardt refinement as the fast path, so that the focal errors
compare the regions and resolution alone). Against it: ``fast``, ``Tracker(...)``'s default (the
region of the last pose at the U-Net's resolution, the two views' segmentation and maps on two
threads), and ``fast-in-turn``, the same with ``parallel_views=False``. These update on the
same frames, and ``net-<name>``, ``fast`` with ``TrackingConfig(network=--network)`` (default
``unet_tracking``: the U-Net trained at input scale 0.25 for the warm regions; docs/tracking.md, "A
network trained for tracking"), in an order that rotates frame by frame so that a slow spell of the machine does not
fall on one of them only. Then, each alone (its worker thread would run on while the others are
timed), ``fast+pipeline`` and ``net+pipeline``: ``Tracker(..., fast=...).track(frames)``, which
segments the next pair while this one is refined; their seconds per pair are the wall time
between two results. With ``--int8``, ``fast-int8`` and ``int8+pipeline``: the same with
``TrackingConfig(precision="int8")`` (docs/tracking.md).

Cine: the physical transducer (0.25 mm render model) on a phantom scene with Poisson noise, on
``default_biplane()`` (960 x 1240), starting at a pose of notebook 04's distribution and moving
``--step-mm`` (0.5) and ``--step-deg`` (0.2) per frame along a drifting direction, about a drifting axis.
Truth: the physical transducer's focal point. Every tracker first runs two untimed updates (numba's
kernels, torch's convolution primitives) and is reset; its first timed update is then from scratch
(timed apart), and from-scratch seconds are also timed on ``--scratch`` later frames (``reset()``
then ``update``), interleaved with ``fast-full``, the fast tracker with
``TrackingConfig(scratch_label_scale=1)``: its from-scratch path before docs/tracking.md "From
scratch in under a second" (UNetRunner.segment on the full frames, then ``estimate_pose``), against
``fast``'s default (``estimate_pose`` at the U-Net's label scale 0.5); with ``--scratch-poses N``
also on one pair each of N independent poses (notebook 04's distribution, each with its own
physical transducer and scene: seeds ``--seed`` + 1000, 1001, ...).

Prints: warm pairs/s (1 / median seconds of the accepted warm updates) and overall pairs/s (all
updates after the first, re-acquisitions included), the median seconds per stage of warm updates,
the ratio to the baseline, the losses and re-acquisitions, each frame's focal error against the
truth and the difference fast - baseline; from-scratch seconds per pair (median, the ratio fast /
fast-full, per stage), acceptance and focal errors. Torch, numba and OpenCV
run on ``--threads`` (2) threads (torch on ``--torch-threads`` where given: with ``parallel_views`` each
view's convolutions then run on that many threads at once); the load average before and after says
how busy the machine was.

It prints the CPU, its instruction sets and the restriction in force first
(:func:`histostudy.core.machine_summary`); ``--isa avx2`` reruns it as on a CPU with AVX2 only
(oneDNN, ATen, numba and numpy held to AVX2, bfloat16 off: :func:`histostudy.core.run_restricted_to`),
on any x86-64 machine. Last, issue 36's three targets against what was measured.

Run: ``python benchmarks/bench_tracking.py [--frames 12] [--seed 5] [--threads 2] [--scratch 2] [--scratch-poses 0]
[--isa native|avx2]``.
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numba
import numpy as np
import torch

from histostudy.core import BENCHMARK_ISAS, machine_summary, run_restricted_to
from histostudy.geometry import transform_from_params
from histostudy.imaging import default_biplane, random_background, render_frame
from histostudy.pose import Tracker, TrackingConfig, default_stages
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.study.pose.geometry import experiment_pose
from histostudy.transducer import TransducerModel

STAGES = ("segmentation", "distance_maps", "refinement", "verdict", "total")


def cine(n_frames: int, seed: int, step_mm: float, step_deg: float):
    """``n_frames`` biplane pairs of a moving transducer: (poses, frames, physical model)."""
    rng = np.random.default_rng(seed)
    views = default_biplane()
    render_model = TransducerModel.build(spacing_mm=0.25)
    physical = TransducerModel.build_physical(spacing_mm=0.25, rng=rng)
    scene = random_background(rng, "phantom")
    T = experiment_pose(rng, PoseStudyConfig(), scene.meta.get("phantom_center_mm", np.zeros(3)))
    direction, axis = (v / np.linalg.norm(v) for v in rng.standard_normal((2, 3)))
    poses, frames = [], []
    for _ in range(n_frames):
        poses.append(T)
        frames.append([render_frame(render_model, T, v, rng=rng, physical=physical, background=scene) for v in views])
        step = transform_from_params(np.r_[np.deg2rad(step_deg) * axis, step_mm * direction])
        T = T.copy()
        T[:3, :3] = step[:3, :3] @ T[:3, :3]
        T[:3, 3] = T[:3, 3] + step[:3, 3]
        direction = direction + 0.3 * rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        axis = axis + 0.3 * rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
    return poses, frames, physical, views


def from_scratch(trackers: dict, pairs: list, truths: list) -> dict:
    """Each tracker's from-scratch estimate (``reset()``, then ``update``) of each pair, interleaved pair
    by pair in a rotating order: per tracker, a list of (seconds, timings, focal error or nan if
    refused, focal point, the fast path's step)."""
    log = {name: [] for name in trackers}
    names = list(trackers)
    for j, (pair, truth) in enumerate(zip(pairs, truths)):
        for name in names[j % len(names):] + names[:j % len(names)]:
            tracker = trackers[name]
            tracker.reset()
            t = time.perf_counter()
            result = tracker.update(pair)
            seconds = time.perf_counter() - t
            error = np.linalg.norm(result.focal_point_mm - truth) if result.verdict.ok else np.nan
            step = tracker._scratch.last_step if tracker._scratch is not None else "full"
            log[name].append((seconds, dict(result.timings_s), error, result.focal_point_mm, step))
    return log


def print_from_scratch(title: str, log: dict) -> None:
    """Seconds (median, each), acceptance, focal errors and the median seconds per stage of
    :func:`from_scratch`'s log; the ratio of the fast path's median to the full frames'."""
    print(f"\nfrom scratch on {title}, interleaved: seconds per pair (median, then each), poses accepted, "
          f"focal error (mm) of the accepted poses; the fast path's steps (scaled / full_frame_warm / full_frame)")
    for n, v in log.items():
        ok = [e[2] for e in v if np.isfinite(e[2])]
        steps = {s: sum(e[4] == s for e in v) for s in dict.fromkeys(e[4] for e in v)}
        print(f"  {n:10s} median {np.median([e[0] for e in v]):.3f} s ({', '.join(f'{e[0]:.2f}' for e in v)}); "
              f"accepted {len(ok)}/{len(v)}; focal error mean {np.mean(ok) if ok else np.nan:.3f}, largest "
              f"{np.max(ok) if ok else np.nan:.3f}; steps {steps}")
    medians = {n: np.median([e[0] for e in v]) for n, v in log.items()}
    print(f"  fast / fast-full: {medians['fast'] / medians['fast-full']:.2f} ({medians['fast']:.3f} s against "
          f"{medians['fast-full']:.3f} s); fast / baseline: {medians['fast'] / medians['baseline']:.2f}")
    apart = np.array([np.linalg.norm(a[3] - b[3]) for a, b in zip(log["fast"], log["fast-full"])])
    excess = np.array([a[2] - b[2] for a, b in zip(log["fast"], log["fast-full"])])
    print(f"  fast vs fast-full: focal points apart mean {apart.mean():.3f} mm, largest {apart.max():.3f} mm; focal "
          f"error fast - fast-full mean {np.nanmean(excess):+.3f} mm, largest {np.nanmax(excess):+.3f} mm")
    print("  median seconds per stage:")
    columns = ("segmentation", "distance_maps", "orientation", "initialisation", "refinement", "verdict", "retries",
               "total")
    print(f"    {'':12s}" + "".join(f"{c[:14]:>15s}" for c in columns))
    for n, v in log.items():
        print(f"    {n:12s}" + "".join(f"{np.median([e[1].get(c, 0.0) for e in v]):15.3f}" for c in columns))


def print_targets(names: list, rate: dict, errors: dict, scratch_s: float) -> None:
    """Issue 36's targets against this run: warm pairs/s of ``track()`` (``fast+pipeline``) and of
    ``update()`` one pair at a time (``fast``), each with its frames' focal errors within 0.1 mm of
    the baseline's either way, and the fast path's median seconds from scratch."""
    def within(n):
        diff = np.abs(errors[n][1:] - errors["baseline"][1:])
        return int(np.sum(diff <= 0.1)), int(np.sum(np.isfinite(diff))), np.nanmax(diff)

    print(f"\nissue 36's targets on {os.cpu_count()} cores ({machine_summary().splitlines()[1]}):")
    for n, label, goal in (("fast+pipeline", "track()", 15.0), ("fast", "update() one pair at a time", 10.0)):
        if n not in names:
            continue
        k, m, largest = within(n)
        verdict = "met" if rate[n] >= goal and k == m else "not met"
        print(f"  {label:28s} {rate[n]:6.2f} warm pairs/s (target >= {goal:g}), {k}/{m} frames within 0.1 mm of "
              f"the baseline (largest |difference| {largest:.3f} mm): {verdict}")
    verdict = "met" if scratch_s <= 0.6 else "not met"
    print(f"  {'from scratch':28s} {scratch_s:6.3f} s a pair (target <= 0.6): {verdict}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--torch-threads", type=int, default=None,
                        help="torch's intra-op threads (default: --threads)")
    parser.add_argument("--step-mm", type=float, default=0.5)
    parser.add_argument("--step-deg", type=float, default=0.2)
    parser.add_argument("--scratch", type=int, default=2, help="later frames also timed from scratch")
    parser.add_argument("--scratch-poses", type=int, default=0,
                        help="also time from scratch one pair each of this many independent poses")
    parser.add_argument("--baseline-mode", choices=("fast", "paper"), default="fast")
    parser.add_argument("--network", default="unet_tracking",
                        help="also track with TrackingConfig(network=NAME), the shipped U-Net trained for tracking "
                             "(warm regions at its input scale; '' leaves it out)")
    parser.add_argument("--int8", action="store_true",
                        help="also track with TrackingConfig(precision='int8') (fast-int8, int8+pipeline)")
    parser.add_argument("--isa", choices=BENCHMARK_ISAS, default="native",
                        help="avx2: run as on a CPU with AVX2 only (the command again, its libraries restricted)")
    args = parser.parse_args()
    run_restricted_to(args.isa)
    print(machine_summary())
    torch.set_num_threads(args.threads if args.torch_threads is None else args.torch_threads)
    numba.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)

    t0 = time.perf_counter()
    poses, frames, physical, views = cine(args.frames, args.seed, args.step_mm, args.step_deg)
    print(f"rendered {args.frames} biplane pairs ({views[0].shape[0]}x{views[0].shape[1]}) in "
          f"{time.perf_counter() - t0:.0f} s; torch/numba/OpenCV threads = "
          f"{torch.get_num_threads()}/{args.threads}/{args.threads}; "
          f"load average before: {os.getloadavg()[0]:.2f}")
    model = TransducerModel.build(spacing_mm=0.47)
    segmenter, orientation = default_stages()
    stages = dict(segmenter=segmenter, orientation=orientation)
    in_turn = TrackingConfig(parallel_views=False)
    trackers = {
        "baseline": Tracker(model, views, rng=args.seed, mode=args.baseline_mode, fast=False, **stages),
        "fast-in-turn": Tracker(model, views, rng=args.seed, mode="fast", fast=in_turn, **stages),
        "fast": Tracker(model, views, rng=args.seed, mode="fast", fast=True, **stages),
    }
    if args.network:
        trackers["net-" + args.network[-8:]] = Tracker(model, views, rng=args.seed, mode="fast",
                                                       fast=TrackingConfig(network=args.network), **stages)
    if args.int8:
        trackers["fast-int8"] = Tracker(model, views, rng=args.seed, mode="fast", fast=TrackingConfig(precision="int8"),
                                        **stages)
    names = list(trackers)
    # Warm-up, untimed: numba's kernels, torch's convolution primitives for these frames' regions.
    for tracker in trackers.values():
        tracker.update(frames[0])
        tracker.update(frames[min(1, args.frames - 1)])
        tracker.reset()
    truth = [T[:3, :3] @ physical.focal_point_mm + T[:3, 3] for T in poses]
    log = {name: [] for name in names}  # per frame: (kind, seconds, timings, focal error or nan)
    for i, pair in enumerate(frames):
        order = names[i % len(names):] + names[:i % len(names)]
        for name in order:
            tracker = trackers[name]
            t = time.perf_counter()
            result = tracker.update(pair)
            seconds = time.perf_counter() - t
            error = np.linalg.norm(result.focal_point_mm - truth[i]) if result.verdict.ok else np.nan
            log[name].append((tracker.last_kind, seconds, dict(result.timings_s), error))
    # Tracker.track overlaps a pair's refinement with the next pair's segmentation on a worker
    # thread, which would run on while the other trackers are timed: it runs alone, after them.
    piped = [("fast+pipeline", TrackingConfig())]
    if args.network:
        piped.append(("net+pipeline", TrackingConfig(network=args.network)))
    if args.int8:
        piped.append(("int8+pipeline", TrackingConfig(precision="int8")))
    for name, options in piped:
        tracker = Tracker(model, views, rng=args.seed, mode="fast", fast=options, **stages)
        list(tracker.track(frames[:2]))
        tracker.reset()
        names.append(name)
        trackers[name] = tracker
        log[name] = []
        stream = tracker.track(iter(frames))
        for i in range(args.frames):
            t = time.perf_counter()
            result = next(stream)
            seconds = time.perf_counter() - t
            error = np.linalg.norm(result.focal_point_mm - truth[i]) if result.verdict.ok else np.nan
            log[name].append((tracker.last_kind, seconds, dict(result.timings_s), error))
        stream.close()
    # From scratch (first updates, re-acquisitions): the baseline (estimate_pose, UNetRunner), the
    # fast tracker's full-frame path before docs/tracking.md "From scratch in under a second"
    # (scratch_label_scale=1: UNetRunner.segment on the full frames, then estimate_pose) and the fast
    # tracker's default (estimate_pose at the U-Net's label scale).
    scratch_trackers = {"baseline": trackers["baseline"],
                        "fast-full": Tracker(model, views, rng=args.seed, mode="fast",
                                             fast=TrackingConfig(scratch_label_scale=1), **stages),
                        "fast": trackers["fast"]}
    scratch_trackers["fast-full"].update(frames[0])  # warm-up, untimed
    scratch_frames = [0] + [k * (args.frames - 1) // max(args.scratch, 1)
                            for k in range(1, 1 + min(args.scratch, args.frames - 1))]
    scratch = from_scratch(scratch_trackers, [frames[i] for i in scratch_frames], [truth[i] for i in scratch_frames])
    independent = None
    if args.scratch_poses:
        pairs, truths = [], []
        for k in range(args.scratch_poses):  # one pair per pose, each pose and transducer of its own seed
            poses_k, frames_k, physical_k, _ = cine(1, args.seed + 1000 + k, args.step_mm, args.step_deg)
            pairs.append(frames_k[0])
            truths.append(poses_k[0][:3, :3] @ physical_k.focal_point_mm + poses_k[0][:3, 3])
        independent = from_scratch(scratch_trackers, pairs, truths)
    load_after = os.getloadavg()[0]

    print(f"\nwarm updates (frames 1-{args.frames - 1}; baseline mode {args.baseline_mode!r}): "
          f"median seconds per stage of the accepted warm updates")
    print(f"{'':16s}" + "".join(f"{n:>15s}" for n in names))
    warm = {n: [e for e in log[n][1:] if e[0] == "warm"] for n in names}
    for s in STAGES:
        print(f"{s:16s}" + "".join(f"{np.median([e[2].get(s, 0.0) for e in warm[n]]) if warm[n] else np.nan:15.3f}"
                                   for n in names))
    rate = {n: 1.0 / np.median([e[1] for e in warm[n]]) if warm[n] else np.nan for n in names}
    overall = {n: (args.frames - 1) / sum(e[1] for e in log[n][1:]) for n in names}
    print(f"{'warm pairs/s':16s}" + "".join(f"{rate[n]:15.2f}" for n in names))
    print(f"{'  x baseline':16s}" + "".join(f"{rate[n] / rate['baseline']:15.2f}" for n in names))
    print(f"{'overall pairs/s':16s}" + "".join(f"{overall[n]:15.2f}" for n in names))
    print(f"{'  x baseline':16s}" + "".join(f"{overall[n] / overall['baseline']:15.2f}" for n in names))
    print(f"{'lost/reacquired':16s}" + "".join(f"{trackers[n].n_lost:>11d}/{trackers[n].n_reacquired:<3d}"
                                                for n in names))
    errors = {n: np.array([e[3] for e in log[n]]) for n in names}
    print(f"{'focal err mean':16s}" + "".join(f"{np.nanmean(errors[n]):15.3f}" for n in names))

    print("\nper frame: kind, seconds, focal error (mm) against the truth; diff: each error - the baseline's")
    print(f"{'frame':>5s}" + "".join(f"{n:>30s}" for n in names) + "  diff: "
          + " ".join(f"{n[:13]:>13s}" for n in names[1:]))
    for i in range(args.frames):
        row = f"{i:5d}"
        for n in names:
            kind, seconds, _, error = log[n][i]
            row += f"{kind:>14s} {seconds:6.3f} s {error:6.3f}"
        row += "        " + " ".join(f"{errors[n][i] - errors['baseline'][i]:+13.3f}" for n in names[1:])
        print(row)
    for n in names[1:]:
        signed = errors[n][1:] - errors["baseline"][1:]
        diff = np.abs(signed)
        print(f"{n}: focal error - baseline's over frames 1-{args.frames - 1}: mean {np.nanmean(signed):+.3f} mm, "
              f"largest {np.nanmax(signed):+.3f} mm (worse than the baseline), |diff| mean {np.nanmean(diff):.3f} mm, "
              f"max {np.nanmax(diff):.3f} mm "
              f"({int(np.sum(diff <= 0.1))}/{int(np.sum(np.isfinite(diff)))} within 0.1 mm)")
    print_from_scratch(f"the cine's frames {scratch_frames}", scratch)
    if independent is not None:
        print_from_scratch(f"{args.scratch_poses} independent poses (seeds {args.seed + 1000}...)", independent)
    print_targets(names, rate, errors, np.median([e[0] for e in scratch["fast"]]))
    print(f"load average after: {load_after:.2f} (on {os.cpu_count()} cores)")


if __name__ == "__main__":
    t_start = time.perf_counter()
    main()
    print(f"(benchmark wall time {time.perf_counter() - t_start:.0f} s)")
