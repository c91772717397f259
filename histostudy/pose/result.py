"""What :func:`~.estimate.estimate_pose` returns (§II-B.3-4): the pose with its cost, timings and
verdict (:class:`PoseResult`), or the error that says the frames support no pose
(:class:`PoseEstimationError`). Poses are 4x4 ``T_carm_transducer`` (mm, C-arm/CBCT frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .init import InitResult
from .refine import RefineResult
from .verdict import PoseVerdict

__all__ = ["PoseEstimationError", "PoseResult", "add_timings", "refused", "result_of_refinement"]


class PoseEstimationError(RuntimeError):
    """The frames do not support a pose (§II-B.3-4): no transducer feature, or an implausible result.

    Args:
        message: what was refused, and why.
        verdict: the failed :class:`~histostudy.pose.verdict.PoseVerdict`, where a pose was judged.
        result: the refused :class:`PoseResult`, where one was refined.
    """

    def __init__(self, message: str, verdict: PoseVerdict | None = None, result: PoseResult | None = None):
        super().__init__(message)
        self.verdict = verdict
        self.result = result


@dataclass
class PoseResult:
    """What :func:`~.estimate.estimate_pose` found (§II-B.3-4).

    Args:
        T_carm_transducer: 4x4 pose, transducer -> C-arm (CBCT) frame, mm.
        focal_point_mm: the model's geometric focal point in the C-arm frame, mm (eq. 5,
            ``f_c = hTc f_h``).
        cost: eq. 3 at the pose (px², summed over views).
        iterations: of the refinement.
        evaluations: of the cost, by the refinement and the initialisation.
        timings_s: seconds per stage: segmentation, distance_maps, orientation, initialisation,
            refinement, verdict, total.
        verdict: the plausibility checks (:class:`~histostudy.pose.verdict.PoseVerdict`).
        mode: ``"paper"`` or ``"fast"``.
        init: the initialisation's record (None for a warm start).
        refine: the refinement's record (:class:`~histostudy.pose.refine.RefineResult`).
        labels: the segmentation of each frame the cost was built on, in that view's pixels.
        retries: initial hypotheses refined after the first failed the verdict.
    """

    T_carm_transducer: np.ndarray
    focal_point_mm: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    timings_s: dict
    verdict: PoseVerdict
    mode: str
    init: InitResult | None
    refine: RefineResult
    labels: list = field(repr=False, default_factory=list)
    retries: int = 0


def add_timings(into: dict, timings: dict) -> None:
    """Adds each stage's seconds of ``timings`` (a :attr:`PoseResult.timings_s`) to ``into``, the running
    sums of a stream of estimates (e.g. the ``stage_seconds`` of :meth:`~histostudy.pose.tracking.Tracker.stats`)."""
    for stage, seconds in timings.items():
        into[stage] = into.get(stage, 0.0) + float(seconds)


def result_of_refinement(refined: RefineResult, verdict: PoseVerdict, focal_point_local_mm, *, mode: str,
                         timings_s: dict, labels: list, init: InitResult | None = None,
                         n_init_evaluations: int = 0, retries: int = 0) -> PoseResult:
    """The :class:`PoseResult` of a refined pose: its focal point in the C-arm frame (eq. 5,
    ``f_c = hTc f_h`` with ``focal_point_local_mm`` in the transducer frame) and its records;
    ``evaluations`` counts the refinement's and ``n_init_evaluations``."""
    T = refined.T
    focal = T[:3, :3] @ np.asarray(focal_point_local_mm, dtype=np.float64) + T[:3, 3]
    return PoseResult(T_carm_transducer=T, focal_point_mm=focal, cost=refined.cost, iterations=refined.iterations,
                      evaluations=refined.evaluations + n_init_evaluations, timings_s=timings_s, verdict=verdict,
                      mode=mode, init=init, refine=refined, labels=labels, retries=retries)


def refused(result: PoseResult) -> PoseEstimationError:
    """The error that reports ``result``'s failed verdict (its reasons, the verdict and the result)."""
    return PoseEstimationError("implausible pose: " + "; ".join(result.verdict.reasons), result.verdict, result)
