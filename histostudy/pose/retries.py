"""The last stages of :func:`~histostudy.pose.estimate_pose_from_labels` (§II-B.3-4): the refinement,
its verdict, and the retries after a refused verdict (:func:`refine_with_retries`; beyond the
paper). Poses are 4x4 ``T_carm_transducer`` (mm, C-arm frame).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .options import PoseConfig
from .refine import RefineResult, refine_pose
from .start import Initialisation
from .truncations import PoseCosts
from .verdict import PoseVerdict

__all__ = ["Refined", "refine_with_retries"]


@dataclass
class Refined:
    """The refinement stage's outcome: the pose kept (``refine.T``), its verdict, and how many
    retries ran."""

    refine: RefineResult
    verdict: PoseVerdict
    retries: int = 0


def refine_with_retries(costs: PoseCosts, judge: Callable[[np.ndarray], PoseVerdict], T_init: np.ndarray,
                        initialisation: Initialisation | None, options: PoseConfig, timings: dict) -> Refined:
    """``T_init`` refined (:func:`~.refine.refine_pose` in ``options.mode``) and judged, then
    retried as docs/pose-estimation.md says where the verdict refuses it and ``initialisation`` (None
    for a warm start: no retries) offers alternatives.

    Writes the seconds of ``"refinement"``, ``"verdict"`` and, when retries ran, ``"retries"``
    into ``timings``; restarts count their searches in ``initialisation``."""
    t0 = time.perf_counter()
    refined = refine_pose(costs, T_init, options.mode)
    timings["refinement"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = Refined(refined, judge(refined.T))
    timings["verdict"] = time.perf_counter() - t0
    if not out.verdict.ok and initialisation is not None and options.retry_hypotheses:
        t0 = time.perf_counter()
        _retry(out, costs, judge, initialisation, options)
        timings["retries"] = time.perf_counter() - t0
    return out


def _retry(out: Refined, costs: PoseCosts, judge, initialisation: Initialisation, options: PoseConfig) -> None:
    """The retries of :func:`refine_with_retries`, each keeping its candidate in ``out`` when it wins."""

    def attempt(T, mode=options.mode, only_if_better=False):
        out.retries += 1
        candidate = refine_pose(costs, T, mode)
        verdict = judge(candidate.T)
        if verdict.ok and (not only_if_better or not out.verdict.ok or candidate.cost < out.refine.cost):
            out.refine, out.verdict = candidate, verdict

    init = initialisation.result
    # The best-scoring initial hypothesis led to an implausible pose: refine the others (other
    # axial minima of §II-B.4's search) and keep the lowest final cost among the plausible ones.
    for T_hyp, _ in sorted(init.hypotheses, key=lambda h: h[1])[1:]:
        attempt(T_hyp, only_if_better=True)
    if not out.verdict.ok and initialisation.deferred_directions:
        # The views agreed on a direction, but it led nowhere plausible: both estimates may be
        # off alike. Start again from each view's own two direction candidates.
        attempt(initialisation.restart(initialisation.deferred_directions).T_carm_transducer)
    if not out.verdict.ok and options.mode == "fast":
        # Last resort: the simplex explores a 2 deg / 2 mm neighbourhood where a gradient step
        # cannot leave a spurious basin of the segmentation errors.
        attempt(init.T_carm_transducer, "paper")
