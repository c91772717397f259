"""Speed of the transducer model build and of point-splatting render (paper §II-B.1-2).

Measures, on this machine:
- model build time at 0.47 mm (pose estimation) and 0.125 mm (rendering), with point counts;
- the render of a 1240x960 frame (default biplane view A, the standard pose) from the 0.125 mm
  model with 16 splats, accumulating with ``np.bincount`` (the method) and, as the baseline on the
  very same splat copies, with ``np.add.at``; the ratio is baseline / chosen, for the accumulation
  alone and for the whole render;
- the reference label render and the peak traced memory of one render.

Usage: ``python benchmarks/bench_render.py [--repeat N]``. Prints figures; asserts nothing on time.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import tracemalloc

import numpy as np

from histostudy.imaging import default_biplane, render_labels, render_line_integrals
from histostudy.imaging.render import _splat_chunks
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
    args = parser.parse_args(argv)
    repeat = max(1, args.repeat)
    print(f"numpy {np.__version__}, python {platform.python_version()}, {os.cpu_count()} CPUs, repeat={repeat}")

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


if __name__ == "__main__":
    main()
