"""What notebook 07's ranges save by estimating each pose experiment's centre only (issue 54): one
range lab's pose experiments run whole and run centre-only (``run_labs(..., centre_only=True)``), on
the same lab, seed and machine, in this process one after the other; the frames rendered, the
estimates made, the seconds of each and their ratio, and that the centres' errors are equal to the bit.

The lab is lab 0 of the error budget's model with ``bubble_offset`` and ``projection`` on (a range
lab keeps such a lab's frames), on half-resolution views of the default biplane and 0.47 mm models
(``--experiments`` pose experiments, 2 splats per point): the seconds are this setting's; the standard
profile's counts scale them (7 acquisitions per experiment whole, 1 centre-only). Asserts nothing.

Usage: ``python benchmarks/bench_budget_ranges.py [--experiments 2]``
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from histostudy.core import machine_summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiments", type=int, default=2, help="pose experiments (default 2)")
    args = parser.parse_args(argv)

    from histostudy.imaging import default_biplane
    from histostudy.study import budget as B
    from histostudy.study.budget._labs import run_labs
    from histostudy.study.budget._run import BudgetSetup
    from histostudy.study.budget._section import budget_seeds
    from histostudy.study.pose.experiments import PoseStudyConfig
    from histostudy.study.targeting.setup import TargetingStudyConfig
    from histostudy.transducer import TransducerModel

    print(machine_summary())
    model = TransducerModel.build(spacing_mm=0.47)
    seeds = budget_seeds(13)
    default = B.LabErrorModel()
    lab_model = dataclasses.replace(default.off(), bubble_offset=default.bubble_offset, projection=default.projection)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    views = [v.scaled(0.5) for v in default_biplane()]
    lab0 = B.draw_lab(lab_model, seeds.lab, physical=physical, views=views, physical_seed=seeds.physical)
    pose = PoseStudyConfig(n_experiments=args.experiments, modes=("fast",), track=False, n_splats=2,
                           background="phantom")
    targeting = TargetingStudyConfig(n_experiments=1, n_splats=2, background="none", bias_correction=False)
    setup = dataclasses.replace(BudgetSetup(lab0, pose, targeting, model, model), seeds=seeds)

    runs = {}
    for centre_only in (False, True):
        t0 = time.perf_counter()
        rows = run_labs(setup, [lab0], seed=seeds.study, studies=("pose",), share=True, centre_only=centre_only,
                        executor="sequential")
        runs[centre_only] = (time.perf_counter() - t0, rows)
    (whole_s, whole), (centre_s, centre) = runs[False], runs[True]
    columns = [c for c in centre.columns if c.startswith("centre_err_")]
    equal = bool(np.array_equal(whole[columns].to_numpy(float), centre[columns].to_numpy(float), equal_nan=True))
    print(f"{args.experiments} pose experiment(s), one lab, sequential:")
    print(f"  whole        {whole_s:7.1f} s  frames made {whole.attrs['frames'][0]}")
    print(f"  centre only  {centre_s:7.1f} s  frames made {centre.attrs['frames'][0]}")
    print(f"  centre only / whole: {centre_s / whole_s:.2f}; centres' errors equal to the bit: {equal}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
