"""Speed of the CBCT phantom, the zone segmentation and the treatment journal (§II-D, §II-E.3-4).

Measures, on this machine, each against a baseline run in the same process:

- ``phantom_volume`` (separable grid coordinates) vs the baseline of evaluating
  ``phantom_values`` on every voxel centre as an (n, 3) point list (same numbers);
- ``segment_treatment_zone`` on a 1 mm post-treatment CBCT vs the baseline ``simulate_cbct``
  that made it (so the ratio says how the segmentation compares with one scanner simulation);
- the journal of ``execute_treatment`` (entries serialised once, file rewritten atomically after
  every point) vs the baseline of ``atomic_write_json`` of the whole journal after every point,
  both on the simulated UR5e; the ratio is per-point wall time, baseline / ours.

Usage: ``python benchmarks/bench_cbct.py [--spacing-mm S]``. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from histostudy import treatment as tr
from histostudy.core import atomic_write_json
from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import cbct
from histostudy.robot import SimulatedUR5e
from histostudy.treatment import TreatmentZone, segment_treatment_zone


def best_of(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing-mm", type=float, default=2.5, help="plan spacing for the journal figure")
    args = parser.parse_args(argv)
    print(f"python {platform.python_version()}, {os.cpu_count()} CPUs")

    spec = cbct.PhantomSpec()
    T = make_transform(rotation_about_axis([1, 1, 0], 0.3), [2.0, -1.0, 3.0])
    t_ours = best_of(lambda: cbct.phantom_volume(spec, T, spacing_mm=1.0, supersample=1))
    vol = cbct.phantom_volume(spec, T, spacing_mm=1.0, supersample=1)
    t_base = best_of(lambda: cbct.phantom_values(vol.world_points().reshape(-1, 3), spec, T))
    print(f"phantom_volume {vol.data.shape} at 1 mm: {t_ours * 1e3:7.1f} ms; pointwise baseline "
          f"{t_base * 1e3:7.1f} ms; ratio {t_base / t_ours:5.1f}x")

    zone = TreatmentZone([1.3, -0.7, 2.2], 20.0)
    roi = cbct.phantom_mask(vol, spec, T)
    post = tr.post_treatment_phantom(vol, zone.mask(vol), roi)
    t_sim = best_of(lambda: cbct.simulate_cbct(post, 0, blur_sigma_mm=0.5, noise_sd_hu=20.0))
    ct = cbct.simulate_cbct(post, 0, blur_sigma_mm=0.5, noise_sd_hu=20.0)
    t_seg = best_of(lambda: segment_treatment_zone(ct, roi))
    print(f"segment_treatment_zone {ct.data.shape}: {t_seg * 1e3:7.1f} ms; simulate_cbct baseline "
          f"{t_sim * 1e3:7.1f} ms; ratio seg/sim {t_seg / t_sim:5.2f}")

    robot = SimulatedUR5e(0)
    T_home = robot.tcp_pose()
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    plan = tr.plan_treatment(zone, args.spacing_mm)
    T_base_carm = make_transform(None, T_home[:3, 3])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        tr.execute_treatment(robot, plan, T_base_carm, T_home[:3, :3], Path(tmp) / "ours.json")
        ours = (time.perf_counter() - t0) / len(plan)
        # baseline: the same moves, the whole journal dict written with atomic_write_json per point
        robot = SimulatedUR5e(0)
        journal = {"plan": plan.to_dict(), "points": []}
        t0 = time.perf_counter()
        for i in range(len(plan)):
            commanded = make_transform(T_home[:3, :3], T_home[:3, 3] + plan.points_mm[i])
            reached = robot.move_linear(commanded, 20.0, 200.0)
            journal["points"].append({"index": i, "commanded_T_base_tcp": commanded, "reached_T_base_tcp": reached})
            atomic_write_json(Path(tmp) / "base.json", journal)
        base = (time.perf_counter() - t0) / len(plan)
    print(f"treatment per point (move + journal), {len(plan)}-point plan: {ours * 1e3:6.2f} ms; whole-dict "
          f"journal baseline {base * 1e3:6.2f} ms; ratio {base / ours:5.1f}x (the baseline grows with the plan)")

if __name__ == "__main__":
    main()
