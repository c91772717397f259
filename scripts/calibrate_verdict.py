"""The verdict's view-agreement bounds measured for a U-Net: which rule on a view's move and on what
that move gains (``PoseConfig.max_view_disagreement_mm``, ``min_view_gain_px2``,
``max_view_gain_px2``) accepts the most right estimates and no wrong one (docs/campaigns.md, "What a
view's move buys").

Each network estimates ``--poses`` random poses of the paper's range (``study.pose.robustness_sweep``,
initialisation "robust", fast mode) on the frames of each ``--renderers`` entry, and tracks the
receiver test's cine (``scripts/tracking_by_network.py``). Every estimate runs with the agreement
bounds out of reach, so each one's per-view figures are measured and none is refused by them (the
fit checks still refuse). Right: within ``--success-mm`` of the truth; grossly wrong: ``--gross-mm``
or more off. Each candidate rule is then applied to the measured figures; a refused estimate counts
as lost (its retries are not run). A rule is safe where it accepts no grossly wrong estimate: an
estimate just beyond ``--success-mm`` whose two views agree is beyond any agreement check.

Renderers: ``reference`` (numpy splatting, the study's 0.125 mm model), ``compiled`` (the compiled
splatter) and ``perturbed`` (the reference with a 1.5x wider splat and half the photons: frames the
network was not trained on).

Usage::

    python scripts/calibrate_verdict.py --poses 40 --workers 2
    python scripts/calibrate_verdict.py --poses 150 --weights /tmp/candidate.safetensors --workers 2
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

#: Agreement bounds out of reach: every estimate's figures are measured, none refused by them.
MEASURE_ONLY_MM = 1e6

#: The renderers' frame settings, as changes to the study's :class:`PoseStudyConfig`.
RENDERERS = {
    "reference": lambda c: c,
    "compiled": lambda c: dataclasses.replace(c, splat_device="cpu"),
    "perturbed": lambda c: dataclasses.replace(c, splat_sigma_mm=1.5 * c.splat_sigma_mm,
                                               photons_per_pixel=0.5 * c.photons_per_pixel),
}


def refuses(rule: tuple, moves: dict, gains: dict) -> bool:
    """Whether ``rule`` = ``(max_move_mm, min_gain_px2, max_gain_px2)`` (None: that bound off)
    refuses an estimate whose views moved ``moves`` (mm) for ``gains`` (px²): the verdict's own
    :func:`histostudy.pose.verdict.agreement_reasons` on those figures."""
    from histostudy.pose.verdict import SingleViewEvidence, agreement_reasons

    evidence = {view: SingleViewEvidence(move_mm=float(move), cost_px2=float(gains[view]), own_optimum_cost_px2=0.0)
                for view, move in moves.items()}
    return bool(agreement_reasons(evidence, rule[0], min_gain_px2=rule[1], max_gain_px2=rule[2]))


def candidate_rules(right_gains: list[float]) -> list[tuple]:
    """Today's rule, moves alone, gains alone and both together, the gain bounds taken at the right
    estimates' quantiles (and 1.1x their largest)."""
    import numpy as np

    gains = np.asarray(right_gains, dtype=np.float64)
    levels = sorted({float(np.quantile(gains, q)) for q in (0.5, 0.75, 0.9, 0.95, 0.99)} | {1.1 * float(gains.max())})
    moves = [1.0, 1.25, 1.5, 2.0, 2.5, 3.0, None]
    rules = {(m, None, None) for m in moves}
    rules |= {(None, None, g) for g in levels}
    rules |= {(m, g, None) for m in moves if m is not None for g in levels}
    rules |= {(m, gmin, gmax) for m in moves for gmin in [None, *levels] for gmax in levels
              if m is not None or gmin is None}
    return sorted(rules, key=lambda r: tuple(float("inf") if v is None else v for v in r))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=40, help="random poses per renderer (default 40)")
    parser.add_argument("--seed", type=int, default=5252, help="the poses' seed (default 5252)")
    parser.add_argument("--weights", action="append", default=[],
                        help="a U-Net checkpoint to measure besides the shipped one (repeatable)")
    parser.add_argument("--renderers", default="reference,perturbed",
                        help=f"comma-separated, of {', '.join(RENDERERS)} (default reference,perturbed)")
    parser.add_argument("--cine-pairs", type=int, default=10, help="pairs of the tracked cine (0: none; default 10)")
    parser.add_argument("--success-mm", type=float, default=2.0, help="right: within this of the truth (default 2)")
    parser.add_argument("--gross-mm", type=float, default=5.0,
                        help="grossly wrong: this far or more from the truth; a rule must accept none (default 5)")
    parser.add_argument("--workers", type=int, default=1, help="processes for the poses (default 1)")
    parser.add_argument("--csv", help="write every measured estimate's figures here")
    args = parser.parse_args(argv)
    renderers = [r.strip() for r in args.renderers.split(",") if r.strip()]
    unknown = [r for r in renderers if r not in RENDERERS]
    if unknown or not renderers:
        parser.error(f"--renderers must name some of {', '.join(RENDERERS)}, got {args.renderers!r}")

    import numpy as np
    import pandas as pd

    from histostudy.core import machine_summary
    from histostudy.imaging import default_biplane
    from histostudy.learning import UNetRunner, default_segmenter, default_vgg19
    from histostudy.pose import ConicOrientation, PoseConfig, Tracker, TrackingConfig
    from histostudy.study.pose import robustness_sweep
    from histostudy.study.pose.experiments import PoseStudyConfig
    from histostudy.transducer import TransducerModel

    print(machine_summary())
    networks = {"shipped": default_segmenter(), **{Path(w).name: UNetRunner.load(w) for w in args.weights}}
    vgg19 = default_vgg19()
    loose = PoseConfig(max_view_disagreement_mm=MEASURE_ONLY_MM)
    views = default_biplane()
    rows = []
    for renderer in renderers:
        config = RENDERERS[renderer](PoseStudyConfig())
        sets = {name: dict(segmenter=unet, orientation=ConicOrientation(segmenter=unet, fallback=vgg19),
                           inits=("robust",)) for name, unet in networks.items()}
        table = robustness_sweep(
            args.poses, pose_model=TransducerModel.build(spacing_mm=0.47),
            render_model=TransducerModel.build(spacing_mm=0.125),
            physical=TransducerModel.build_physical(spacing_mm=0.125, rng=np.random.default_rng(args.seed)),
            views=views, seed=args.seed, config=config, stage_sets=sets, pose_options=loose,
            success_mm=args.success_mm, executor=f"local:{args.workers}" if args.workers > 1 else "sequential")
        for _, r in table.iterrows():
            measured = {v.name: float(r.get(f"disagreement_mm_{v.name}", np.nan)) for v in views}
            rows.append({"network": r["stages"], "set": renderer, "item": int(r["pose"]), "error_mm": r["error_mm"],
                         "fit_ok": bool(r["verdict_ok"]) and all(np.isfinite(m) for m in measured.values()),
                         **{f"move_mm_{k}": m for k, m in measured.items()},
                         **{f"gain_px2_{v.name}": float(r.get(f"gain_px2_{v.name}", np.nan)) for v in views}})
    if args.cine_pairs:
        from tracking_by_network import cine_frames

        poses, pairs = cine_frames(args.cine_pairs)
        model = TransducerModel.build(spacing_mm=0.47)
        for name, unet in networks.items():
            orientation = ConicOrientation(segmenter=unet, fallback=vgg19)
            tracker = Tracker(model, views, segmenter=unet, orientation=orientation, rng=0,
                              fast=TrackingConfig(scratch_full_frames=False), mode="fast", retry_hypotheses=False,
                              max_view_disagreement_mm=MEASURE_ONLY_MM, raise_on_failure=False)
            for i, pair in enumerate(pairs):
                result = tracker.update(pair)
                v = result.verdict
                error = float(np.linalg.norm(result.T_carm_transducer[:3, 3] - poses[i][:3, 3]))
                rows.append({"network": name, "set": "cine", "item": i, "error_mm": error,
                             "fit_ok": v.ok and bool(v.view_disagreement_mm),
                             **{f"move_mm_{k}": m for k, m in v.view_disagreement_mm.items()},
                             **{f"gain_px2_{k}": g for k, g in v.view_gain_px2.items()}})
    measured = pd.DataFrame(rows)
    if args.csv:
        measured.to_csv(args.csv, index=False)
    names = [v.name for v in views]
    for network, of_network in measured.groupby("network", sort=False):
        judged = of_network[of_network["fit_ok"]]
        right = (judged["error_mm"] < args.success_mm).to_numpy()
        gross = (judged["error_mm"] >= args.gross_mm).to_numpy()
        print(f"\n## {network}: {len(of_network)} estimates; {int((~of_network['fit_ok']).sum())} refused by the fit "
              f"checks; of the rest {int(right.sum())} right, {int((~right).sum())} wrong (>= {args.success_mm} mm), "
              f"{int(gross.sum())} of them grossly (>= {args.gross_mm} mm)")
        per_view = [({n: r[f"move_mm_{n}"] for n in names}, {n: r[f"gain_px2_{n}"] for n in names})
                    for _, r in judged.iterrows()]
        right_gains = [g for (_, gains), ok in zip(per_view, right) if ok for g in gains.values()]
        if not right_gains:
            print("no right estimate measured: no rule to choose")
            continue
        results = []
        for rule in candidate_rules(right_gains):
            refused = np.array([refuses(rule, moves, gains) for moves, gains in per_view], dtype=bool)
            entry = {"max move (mm)": rule[0], "min gain (px²)": rule[1], "max gain (px²)": rule[2],
                     "gross accepted": int((gross & ~refused).sum()), "wrong accepted": int((~right & ~refused).sum())}
            for subset in judged["set"].unique():
                inside = (judged["set"] == subset).to_numpy()
                entry[f"right accepted, {subset}"] = (f"{int((right & ~refused & inside).sum())} of "
                                                      f"{int((right & inside).sum())}")
            entry["right accepted"] = int((right & ~refused).sum())
            results.append(entry)
        table = pd.DataFrame(results)
        today = table[(table["max move (mm)"] == 1.5) & table["min gain (px²)"].isna()
                      & table["max gain (px²)"].isna()]
        safe = table[table["gross accepted"] == 0].sort_values(["right accepted", "wrong accepted"],
                                                               ascending=[False, True], kind="stable")
        print("today's rule (move 1.5 mm):\n" + today.to_markdown(index=False, floatfmt=".3f"))
        print("\nthe rules that accept no grossly wrong estimate, most right accepted first:\n"
              + (safe.head(8).to_markdown(index=False, floatfmt=".3f") if len(safe) else "none"))
        print(f"\nlargest gain of a right estimate: {max(right_gains):.3f} px²; the wrong estimates that passed "
              "the fit checks:\n" + (judged[~right].drop(columns=["network", "fit_ok"]).to_markdown(
                  index=False, floatfmt=".3f") if (~right).any() else "none"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
