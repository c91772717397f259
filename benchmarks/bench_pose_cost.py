"""Speed of the pose cost (eq. 3, §II-B.3) and of the two refinements, against stated baselines.

Prints, for the 0.47 mm digital model on the paper's two 1240x960 views (default_biplane):
- the distance-map construction time per view (5 exact EDTs);
- numba JIT compile time (fresh cache, in a subprocess) and cache-load time;
- cost evaluations per second: fused numba kernel (all threads, one thread) vs the numpy float64
  reference, and the ratio to the *gather floor* measured in the same run: the time numpy takes
  for a random gather ``map.ravel()[idx]`` of as many float32 values (one per projected point and
  view) from one 1240x960 float32 map (which stays in the caches), and the same gather spread
  over all the maps eq. 3 reads (which does not); a numba prange sum-gather of the same indices, and of
  four neighbours per index (what bilinear interpolation reads) are printed beside it;
- the Levenberg-Marquardt Jacobian pass (cost + J'J + J'r fused) and the materialised n x 6 one;
- Nelder-Mead (paper settings) vs Levenberg-Marquardt from the same perturbed starts: time,
  evaluations and focal-point / rotation error, on the reference label image (overlap priority,
  0.125 mm model) with eq. 3's per-class maps and with occlusion-aware maps, and on per-class
  masks (no occlusion).

Run: ``python benchmarks/bench_pose_cost.py [--repeat 30] [--starts 3]``. Times are the median
(and best) of ``--repeat`` calls; on a shared machine the best is the steadier figure.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import textwrap
import time

import numba
import numpy as np

from histostudy.geometry import rotation_angle
from histostudy.imaging import default_biplane, render_labels
from histostudy.pose import (
    DistanceMaps,
    PoseCost,
    apply_left_perturbation,
    refine_levenberg_marquardt,
    refine_nelder_mead,
)
from histostudy.transducer import FEATURE_CLASSES, TransducerModel, pose_facing


def timed(fn, repeat: int) -> tuple[float, float]:
    """(median, best) seconds of ``repeat`` calls after one warm-up call."""
    fn()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), float(np.min(ts))


def ms(pair) -> str:
    return f"{pair[0] * 1e3:8.3f} ms (best {pair[1] * 1e3:.3f})"


@numba.njit(parallel=True, cache=True)
def _sum_gather(values, idx):
    s = 0.0
    for i in numba.prange(idx.size):
        s += values[idx[i]]
    return s


@numba.njit(parallel=True, cache=True)
def _sum_gather4(values, idx, stride):
    s = 0.0
    for i in numba.prange(idx.size):
        j = idx[i]
        s += values[j] + values[j + 1] + values[j + stride] + values[j + stride + 1]
    return s


def jit_times() -> tuple[float, float]:
    """(compile, cache load) seconds of the three cost kernels, in fresh subprocesses."""
    code = textwrap.dedent("""
        import time, numpy as np
        from histostudy.imaging.carm import default_biplane
        from histostudy.pose import DistanceMaps, PoseCost
        from histostudy.transducer import Feature
        view = default_biplane()[0]
        labels = np.zeros(view.shape, np.uint8); labels[400:500, 500:600] = 1
        maps = [DistanceMaps(view, labels)]
        t = time.perf_counter()
        for parallel in (False, True):
            cost = PoseCost({Feature.TRANSDUCER: np.zeros((10, 3))}, maps, parallel=parallel)
            cost(np.eye(4)); cost.normal_equations(np.eye(4)); cost.residuals_and_jacobian(np.eye(4))
        print(time.perf_counter() - t)
    """)
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = [float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                    check=True).stdout.strip().splitlines()[-1]) for _ in range(2)]
    return out[0], out[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--starts", type=int, default=3, help="perturbed starts for the refinement comparison")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    print(f"numba {numba.__version__}, {numba.get_num_threads()} threads, numpy {np.__version__}")
    compile_s, load_s = jit_times()
    print(f"JIT: compile {compile_s:.2f} s (fresh cache), cache load {load_s:.2f} s "
          f"(cost, normal-equation and residual kernels, threaded and serial)")

    views = default_biplane()
    T_true = pose_facing(focal_point_mm=(5.0, -3.0, 8.0), axial_rotation_rad=0.3)
    model = TransducerModel.build(spacing_mm=0.47)
    fine = TransducerModel.build(spacing_mm=0.125)
    labels = [render_labels(fine, T_true, v) for v in views]
    t = time.perf_counter()
    maps = [DistanceMaps(v, lab) for v, lab in zip(views, labels)]
    print(f"DistanceMaps: {(time.perf_counter() - t) / len(views) * 1e3:.1f} ms per 1240x960 view (5 classes)")

    cost = PoseCost(model.points, maps)
    reference = PoseCost(model.points, maps, backend="numpy")
    n_proj = cost.n_total * len(views)
    print(f"model: {cost.n_total} points (0.47 mm), {len(views)} views -> {n_proj} projections per evaluation")

    rng = np.random.default_rng(args.seed)
    T = apply_left_perturbation(T_true, [0.01, -0.02, 0.005, 1.0, -2.0, 0.5])
    flat = maps[0].maps[FEATURE_CLASSES[0]].ravel()
    idx = rng.integers(0, flat.size - views[0].shape[1] - 2, n_proj)
    floor = timed(lambda: flat[idx], args.repeat)
    # The same gather over all the maps eq. 3 reads (every class in every view, ~47 MB, beyond the
    # caches) instead of one 4.7 MB map that stays in them: the floor a real evaluation faces.
    idx_all = rng.integers(0, cost._maps.size - views[0].shape[1] - 2, n_proj)
    floor_all = timed(lambda: cost._maps[idx_all], args.repeat)
    gather1 = timed(lambda: _sum_gather(flat, idx), args.repeat)
    gather4 = timed(lambda: _sum_gather4(flat, idx, views[0].shape[1]), args.repeat)
    threads = numba.get_num_threads()
    threaded = PoseCost(model.points, maps, parallel=True)
    serial = PoseCost(model.points, maps, parallel=False)
    fast = timed(lambda: threaded(T), args.repeat)
    fast1 = timed(lambda: serial(T), args.repeat)
    numba.set_num_threads(1)
    gather4_1 = timed(lambda: _sum_gather4(flat, idx, views[0].shape[1]), args.repeat)
    numba.set_num_threads(threads)
    sub = cost.subset(1500, np.random.default_rng(args.seed))
    sub_threaded = PoseCost(sub.points, maps, parallel=True)
    sub_serial = PoseCost(sub.points, maps, parallel=False)
    small_threaded = timed(lambda: sub_threaded(T), args.repeat)
    small_serial = timed(lambda: sub_serial(T), args.repeat)
    # A grid search's 130 nodes (the paper's coarse grid) on the subset: one call per node vs one
    # batched call (the rotation folded once, the nodes spread over the threads).
    nodes = T[:3, 3] + rng.normal(scale=30.0, size=(130, 3))
    per_node = timed(lambda: [sub_threaded(np.vstack([np.c_[T[:3, :3], t], [0, 0, 0, 1]])) for t in nodes],
                     max(3, args.repeat // 5))
    batched = timed(lambda: sub_threaded.costs_at_translations(T[:3, :3], nodes), max(3, args.repeat // 5))
    ref = timed(lambda: reference(T), max(3, args.repeat // 5))
    normal = timed(lambda: threaded.normal_equations(T), args.repeat)
    normal1 = timed(lambda: serial.normal_equations(T), args.repeat)
    materialised = timed(lambda: cost.residuals_and_jacobian(T), max(3, args.repeat // 5))
    # A distance cap (estimate_pose caps its searches, refinement and verdict): applied in the
    # kernels by PoseCost.capped, against the baseline of copying capped maps into a new cost.
    capped = threaded.capped(1.0)
    capped_eval = timed(lambda: capped(T), args.repeat)
    build_capped = timed(lambda: threaded.capped(1.0), args.repeat)
    build_copy = timed(lambda: PoseCost(model.points, [m.truncated(1.0) for m in maps], parallel=True),
                       max(3, args.repeat // 5))
    assert abs(cost(T) - reference(T)) <= 1e-9 * reference(T)

    print(f"\ncost evaluation ({n_proj} projections):")
    print(f"  gather floor (numpy random gather, {n_proj} float32) {ms(floor)}")
    print(f"  gather over all {int(cost.active.sum())} active maps ({cost._maps.nbytes / 2**20:.0f} MB)"
          f"          {ms(floor_all)}  "
          f"-> fused cost {fast[0] / floor_all[0]:.2f}x this floor")
    print(f"  numba sum-gather, 1 value/index                   {ms(gather1)}")
    print(f"  numba sum-gather, 4 values/index (bilinear reads) {ms(gather4)}   1 thread {ms(gather4_1)}")
    print(f"  numba fused cost, {threads} threads                       {ms(fast)}  -> {1 / fast[0]:7.0f} eval/s, "
          f"{fast[0] / floor[0]:.2f}x floor (best {fast[1] / floor[1]:.2f}x)")
    print(f"  numba fused cost, serial                          {ms(fast1)}  -> {1 / fast1[0]:7.0f} eval/s, "
          f"{fast1[0] / floor[0]:.2f}x floor (best {fast1[1] / floor[1]:.2f}x)")
    print(f"  subset cost ({sub.n_total} points) threaded / serial   {ms(small_threaded)} / {ms(small_serial)}")
    print(f"  130 grid nodes, subset: one call per node / batched {ms(per_node)} / {ms(batched)}  "
          f"-> batched {per_node[0] / batched[0]:.1f}x faster")
    print(f"  numpy float64 reference                           {ms(ref)}  -> {1 / ref[0]:7.0f} eval/s, "
          f"numba is {ref[0] / fast[0]:.0f}x faster")
    print(f"  LM pass: cost + J'J + J'r fused, {threads} threads        {ms(normal)}  "
          f"({normal[0] / fast[0]:.1f}x a cost evaluation)")
    print(f"  LM pass: cost + J'J + J'r fused, serial           {ms(normal1)}  "
          f"({normal1[0] / fast1[0]:.1f}x a cost evaluation)")
    print(f"  residuals + n x 6 Jacobian materialised           {ms(materialised)}")
    print(f"  capped at 1 px: evaluation                        {ms(capped_eval)}  "
          f"({capped_eval[0] / fast[0]:.2f}x uncapped)")
    print(f"  capped cost built by PoseCost.capped              {ms(build_capped)}  "
          f"vs copied maps (DistanceMaps.truncated) {ms(build_copy)} -> {build_copy[0] / build_capped[0]:.0f}x faster")

    masks = [DistanceMaps(v, {f: render_labels(fine.only(f), T_true, v) == int(f) for f in FEATURE_CLASSES})
             for v in views]
    print("\nrefinement from 3 deg / 5 mm perturbations (focal-point error mm, rotation error deg):")
    aware = [DistanceMaps(v, lab, occlusion_aware=True) for v, lab in zip(views, labels)]
    for name, cmaps in (("label image (priority), eq. 3's per-class maps", maps),
                        ("label image (priority), occlusion-aware maps", aware),
                        ("per-class masks", masks)):
        c = PoseCost(model.points, cmaps)
        coarse = c.subset(2000, np.random.default_rng(args.seed))
        rows = {"nelder-mead": [], "levenberg-marquardt": [], "LM coarse-to-fine": []}
        for k in range(args.starts):
            r = np.random.default_rng(args.seed + 100 + k)
            axis, direction = r.normal(size=3), r.normal(size=3)
            T0 = apply_left_perturbation(T_true, np.r_[axis / np.linalg.norm(axis) * np.deg2rad(3.0),
                                                       direction / np.linalg.norm(direction) * 5.0])
            for key, fn in (("nelder-mead", lambda c=c, T0=T0: refine_nelder_mead(c, T0)),
                            ("levenberg-marquardt", lambda c=c, T0=T0: refine_levenberg_marquardt(c, T0)),
                            ("LM coarse-to-fine",
                             lambda c=c, T0=T0, coarse=coarse: refine_levenberg_marquardt(c, T0, coarse=coarse))):
                res = fn()
                rows[key].append((res.seconds, res.evaluations, np.linalg.norm(res.T[:3, 3] - T_true[:3, 3]),
                                  np.rad2deg(rotation_angle(res.T[:3, :3].T @ T_true[:3, :3]))))
        print(f"  {name} (cost at truth {c(T_true):.3f}):")
        for key, vals in rows.items():
            a = np.array(vals)
            print(f"    {key:20s} {a[:, 0].mean():6.3f} s  {a[:, 1].mean():6.1f} evals  "
                  f"focal err mean {a[:, 2].mean():.3f} max {a[:, 2].max():.3f} mm  "
                  f"rot err max {a[:, 3].max():.3f} deg")


if __name__ == "__main__":
    main()
