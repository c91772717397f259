"""Speed of the transducer model build and of point-splatting render (paper §II-B.1-2).

Measures, on this machine:
- model build time at 0.47 mm (pose estimation) and 0.125 mm (rendering), with point counts;
- the render of a 1240x960 frame (default biplane view A, the standard pose) from the 0.125 mm
  model with 16 splats, accumulating with ``np.bincount`` (the method) and, as the baseline on the
  very same splat copies, with ``np.add.at``; the ratio is baseline / chosen, for the accumulation
  alone and for the whole render;
- the reference label render and the peak traced memory of one render;
- the renderers side by side (``render_frame(device=...)``, docs/training.md "Renderers"): training
  frames as ``HybridFrames`` makes them (random pose and view, mixed anatomy, 0.125 mm physical
  model, labels, Poisson noise) on the numpy reference (the baseline, ``device=None``), compiled on
  the CPU (``"cpu"``) and, where CUDA is present, torch on the GPU; the splatting alone also on
  torch's CPU path; ratios are baseline / renderer, on the same frames;
- with CUDA, the GPU's batch throughput (``TorchSplatter.line_integrals`` and noise, ``--batch``
  frames per call, full size) in frames per second.

Usage: ``python benchmarks/bench_render.py [--repeat N] [--frames K] [--skip-accumulators]``.
Prints the machine (CPU model, ISA, restriction) and figures; asserts nothing on time.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import tracemalloc

import numpy as np

from histostudy.core import machine_summary
from histostudy.imaging import default_biplane, random_background, render_frame, render_labels, render_line_integrals
from histostudy.imaging.render import TorchSplatter, poisson_noise_torch
from histostudy.imaging.render._reference import _splat_chunks  # the splat alone, as the renderer runs it
from histostudy.transducer import FEATURE_CLASSES, TransducerModel, pose_facing


def timed(fn, repeat: int) -> tuple[float, float, object]:
    """(best, median) wall time in s over ``repeat`` runs, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times)), result


def render_with(accumulate: str, model, T, view, seed: int) -> tuple[np.ndarray, float]:
    """The splat render with the given accumulator; returns the image and the accumulation time."""
    rows, cols = view.shape
    image = np.zeros(rows * cols)
    spent = 0.0
    for flat, values in _splat_chunks(model, T, view, rng=np.random.default_rng(seed), n_splats=16,
                                      splat_sigma_mm=0.5):
        t0 = time.perf_counter()
        if accumulate == "bincount":
            image += np.bincount(flat, weights=values, minlength=rows * cols)
        else:
            np.add.at(image, flat, values)
        spent += time.perf_counter() - t0
    return image.reshape(rows, cols), spent


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per measurement (best and median shown)")
    parser.add_argument("--frames", type=int, default=4, help="training frames per renderer (default 4)")
    parser.add_argument("--batch", type=int, default=16, help="frames per call of the GPU batch (default 16)")
    parser.add_argument("--skip-accumulators", action="store_true",
                        help="only the renderers side by side (skip the model builds, accumulators and labels)")
    args = parser.parse_args(argv)
    repeat = max(1, args.repeat)
    print(machine_summary())
    print(f"numpy {np.__version__}, python {platform.python_version()}, {os.cpu_count()} CPUs, repeat={repeat}")
    if args.skip_accumulators:
        renderers(max(1, args.frames), max(1, args.batch))
        return

    models = {}
    for spacing in (0.47, 0.125):
        best, median, model = timed(lambda s=spacing: TransducerModel.build(spacing_mm=s), repeat)
        models[spacing] = model
        counts = ", ".join(f"{f.name}={model.n_points[f]:,}" for f in FEATURE_CLASSES)
        print(f"build {spacing:5.3f} mm: best {best:6.3f} s, median {median:6.3f} s; "
              f"{sum(model.n_points.values()):,} points ({counts})")

    fine = models[0.125]
    view_a, _ = default_biplane()
    T = pose_facing()
    copies = 16 * int(sum((fine.weights[f] > 0).sum() for f in FEATURE_CLASSES))
    print(f"render: view {view_a.name} {view_a.shape[1]}x{view_a.shape[0]}, 0.125 mm model, 16 splats "
          f"= {copies:,} copies")

    results = {}
    for method in ("bincount", "add.at"):
        runs = [timed(lambda m=method: render_with(m, fine, T, view_a, seed=0), 1) for _ in range(repeat)]
        totals = [r[0] for r in runs]
        accum = [r[2][1] for r in runs]
        results[method] = (min(totals), min(accum), runs[-1][2][0])
        print(f"  {method:8s}: render best {min(totals):6.3f} s (median {np.median(totals):6.3f}), "
              f"accumulation best {min(accum):6.3f} s")
    b, a = results["bincount"], results["add.at"]
    print(f"  ratio add.at / bincount: accumulation {a[1] / b[1]:5.2f}x, whole render {a[0] / b[0]:5.2f}x; "
          f"images agree to {np.abs(a[2] - b[2]).max():.2e}")

    best, median, _ = timed(lambda: render_line_integrals(fine, T, view_a, rng=np.random.default_rng(0)), repeat)
    print(f"render_line_integrals (public): best {best:6.3f} s, median {median:6.3f} s")
    best, median, _ = timed(lambda: render_labels(fine, T, view_a), repeat)
    print(f"render_labels 0.125 mm: best {best:6.3f} s, median {median:6.3f} s")
    best, median, _ = timed(lambda: render_labels(models[0.47], T, view_a), repeat)
    print(f"render_labels 0.47 mm:  best {best:6.3f} s, median {median:6.3f} s")

    tracemalloc.start()
    render_line_integrals(fine, T, view_a, rng=np.random.default_rng(0))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"peak traced memory of one 0.125 mm render: {peak / 2**20:,.0f} MiB")
    renderers(max(1, args.frames), max(1, args.batch))


def renderers(n_frames: int, batch: int) -> None:
    """The renderers side by side on the same training frames (module docstring)."""
    import torch

    from histostudy.learning import HybridFrames
    from histostudy.learning.datasets import _models, random_training_pose

    frames = HybridFrames("train", seed=0)
    digital, physical = _models(0.125, 0.125, 0)
    scenes = []
    for i in range(n_frames):
        rng = np.random.default_rng(frames.seed_sequence(i).spawn(2)[1])
        view = frames.view(i)
        scenes.append((view, random_training_pose(rng, view), random_background(rng, "mixed")))

    def frame_seconds(device) -> list[float]:
        times = []
        for i, (view, T, anatomy) in enumerate(scenes):
            t0 = time.perf_counter()
            render_frame(digital, T, view, rng=np.random.default_rng(i), physical=physical, background=anatomy,
                         device=device)
            times.append(time.perf_counter() - t0)
        return times

    devices = [None, "cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices[1:]:  # compile numba's kernel, load CUDA's, outside the timing
        render_frame(digital, scenes[0][1], scenes[0][0], rng=np.random.default_rng(0), physical=physical,
                     background=scenes[0][2], device=device)
    print(f"renderers: {n_frames} training frames ({scenes[0][0].shape[1]}x{scenes[0][0].shape[0]}, mixed anatomy, "
          f"0.125 mm physical model, labels, noise), render_frame per device; torch threads {torch.get_num_threads()}")
    baseline = None
    for device in devices:
        times = frame_seconds(device)
        median = float(np.median(times))
        baseline = median if baseline is None else baseline
        label = "numpy" if device is None else device
        print(f"  frame  {label:6s}: median {median:6.3f} s, best {min(times):6.3f} s; "
              f"ratio numpy / this {baseline / median:5.2f}x")

    # the splatting alone: numpy reference, compiled, torch's CPU path (what CUDA runs, on the CPU)
    splat = {}
    for name in ("numpy", "cpu", "torch-cpu"):
        times = []
        for i, (view, T, _) in enumerate(scenes):
            t0 = time.perf_counter()
            if name == "torch-cpu":
                TorchSplatter(physical, "cpu").line_integrals([T], [view], [i])
            else:
                render_line_integrals(physical, T, view, rng=np.random.default_rng(i),
                                      device=None if name == "numpy" else "cpu")
            times.append(time.perf_counter() - t0)
        splat[name] = float(np.median(times))
        print(f"  splat  {name:9s}: median {splat[name]:6.3f} s; "
              f"ratio numpy / this {splat['numpy'] / splat[name]:5.2f}x")

    if torch.cuda.is_available():
        splatter = TorchSplatter(physical, "cuda")
        views = [scenes[i % n_frames][0] for i in range(batch)]
        poses = [scenes[i % n_frames][1] for i in range(batch)]
        splatter.line_integrals(poses[:1], views[:1], [0])
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        for call in range(3):
            images = splatter.line_integrals(poses, views, range(call * batch, (call + 1) * batch))
            poisson_noise_torch(images, 5e4, seed=call)
        torch.cuda.synchronize()
        seconds = time.perf_counter() - t0
        print(f"  GPU batch ({torch.cuda.get_device_name()}): {3 * batch / seconds:6.1f} frames/s "
              f"(splatting and noise; {batch} a call, full size)")


if __name__ == "__main__":
    main()
