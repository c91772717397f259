"""The initialisation stage of :func:`~histostudy.pose.estimate_pose_from_labels` (§II-B.4): the
directions to start from (eq. 4), then per direction the grid and axial searches, as the paper
(``init="paper"``) or robustly (``init="robust"``, beyond the paper). Poses are 4x4
``T_carm_transducer`` (mm), directions unit vectors in the C-arm frame.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from histostudy.imaging import View
from histostudy.learning import select_direction
from histostudy.transducer import Feature, TransducerModel

from .init import MEDIUM_GRID, PAPER_AXIAL_SEEDS_DEG, ROBUST_AXIAL_SEEDS_DEG, InitResult, initialise_pose
from .options import PoseConfig
from .refine import refine_levenberg_marquardt
from .silhouette import silhouette_candidates
from .truncations import PoseCosts

__all__ = ["SILHOUETTE_POINTS", "Initialisation", "coarse_scorings", "directions_to_try", "initialise"]

#: Model points (elements and outer boundary) whose projected occupancy the robust
#: initialisation's silhouette seed compares with the segmented one.
SILHOUETTE_POINTS = 4000


def coarse_scorings(costs: PoseCosts, options: PoseConfig, n_views: int, rng: np.random.Generator) -> list | None:
    """The robust initialisation's scorings of the coarse grids, ``[(per-view costs, joint cost)]``
    (:func:`~.init.initialise_pose`'s ``coarse_scorings``); None with ``init="paper"``.

    Draws their point subset from ``rng`` (a fifth of ``init_points_per_class`` per class)."""
    if options.init != "robust":
        return None
    tau_coarse = float(options.coarse_truncation_px)
    # Off the detector a point is unknown. Costing it the full truncation, a pose that pulls
    # more of the model into a view where the transducer is mostly outside can beat the true
    # region; at half the truncation a pose with most of the model off the detectors can
    # beat a near miss of the coarse grid (both measured). Each scoring proposes its chains;
    # the narrower search cost decides after the medium and fine grids.
    # A 3 cm grid needs no more than a few hundred points per class to rank its nodes.
    subset = costs.coarse.subset(max(1, options.init_points_per_class // 5), rng)
    full = subset.capped(tau_coarse, outside_distance_px=tau_coarse)
    return [([c.select_views(i) for i in range(n_views)], c)
            for c in (full, full.with_outside_distance(0.5 * tau_coarse))]


def directions_to_try(candidates: Sequence[np.ndarray], options: PoseConfig) -> tuple[list, list, float | None]:
    """``(directions to start from, directions deferred to a retry, spread_rad)`` of the views'
    ``(2, 3)`` candidate pairs.

    One view: both mirrors (the lower cost decides). Two or more: their best agreement
    (:func:`~histostudy.learning.select_direction`); with ``init="robust"`` each view's own two
    candidates are added when the views disagree by more than ``direction_spread_limit_deg``, else
    deferred to a retry after a refused verdict. ``spread_rad``: the views' mean pairwise angle
    (None with one view)."""
    if len(candidates) == 1:
        return [candidates[0][0], candidates[0][1]], [], None
    direction, _, spread = select_direction(candidates)
    tries, deferred = [direction], []
    if options.init == "robust":
        per_view = [c for view_candidates in candidates for c in view_candidates]
        if np.rad2deg(spread) > options.direction_spread_limit_deg:
            tries += per_view
        else:
            deferred = per_view
    return tries, deferred, spread


@dataclass
class Initialisation:
    """What the initialisation stage found, and how to start again.

    Attributes:
        result: the best start's :class:`~.init.InitResult` (``stages["direction_starts"]``: how
            many directions were started from; ``stages["direction_spread_deg"]`` with two or
            more views).
        n_evaluations: cost evaluations of the searches run so far (:meth:`restart` adds its own).
        deferred_directions: directions for a retry after a refused verdict (see
            :func:`directions_to_try`).
        search: ``directions -> (best InitResult, n_evaluations)``, the searches run again.
    """

    result: InitResult
    n_evaluations: int
    deferred_directions: list
    search: Callable[[Sequence[np.ndarray]], tuple[InitResult, int]]

    def restart(self, directions: Sequence[np.ndarray]) -> InitResult:
        """The searches from ``directions``; counts them in :attr:`n_evaluations` and
        ``result.stages["direction_starts"]``, and returns their best start."""
        best, n_eval = self.search(directions)
        self.n_evaluations += n_eval
        self.result.stages["direction_starts"] += len(directions)
        return best


def initialise(candidates: Sequence[np.ndarray], views: Sequence[View], labels: Sequence[np.ndarray],
               model: TransducerModel, costs: PoseCosts, scorings: list | None, options: PoseConfig,
               rng: np.random.Generator) -> Initialisation:
    """The initialisation from each view's ``(2, 3)`` direction ``candidates`` (docs/pose-estimation.md).

    ``scorings``: :func:`coarse_scorings`' (robust). Draws from ``rng`` the silhouette seed's model
    points (robust, two or more views)."""
    views = list(views)
    tries, deferred, spread = directions_to_try(candidates, options)
    view_costs = [costs.search.select_views(i) for i in range(len(views))]
    search_options = _search_options(views, labels, model, costs, scorings, options, rng)

    def search(directions):
        results = [initialise_pose(d, views, view_costs, costs.search, centre_mm=options.search_centre_mm,
                                   **search_options) for d in directions]
        return min(results, key=lambda r: r.cost), sum(r.n_evaluations for r in results)

    result, n_eval = search(tries)
    result.stages["direction_starts"] = len(tries)
    if spread is not None:
        result.stages["direction_spread_deg"] = float(np.rad2deg(spread))
    return Initialisation(result, n_eval, deferred, search)


def _search_options(views, labels, model, costs: PoseCosts, scorings, options: PoseConfig, rng) -> dict:
    """:func:`~.init.initialise_pose`'s keywords for ``options.init``."""
    if options.init != "robust":
        return dict(axial_seeds_deg=PAPER_AXIAL_SEEDS_DEG, fine_after_axial=False, n_hypotheses=1)

    def polish(T):
        # Truncated distances: points on missed or hidden features do not pull. Scored by
        # the search cost, so that hypotheses compare as the grids and axial search did.
        r = refine_levenberg_marquardt(costs.polish, T, max_iter=30)
        return r.T, float(costs.search(r.T))

    out = dict(axial_seeds_deg=ROBUST_AXIAL_SEEDS_DEG, fine_after_axial=True, n_hypotheses=3, polish=polish,
               medium=MEDIUM_GRID, coarse_scorings=scorings, coarse_candidates=3)
    if len(views) > 1:
        silhouettes = [lab > 0 for lab in labels]
        body = np.vstack([model.points[k] for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY) if k in model.points])
        body = body[rng.choice(len(body), size=min(len(body), SILHOUETTE_POINTS), replace=False)]
        centre_local = body.mean(axis=0)
        out["seeded"] = lambda d: [(a, t) for a, t, _ in silhouette_candidates(
            d, views, silhouettes, body, centre_local_mm=centre_local)]
    return out
