"""Pose initialisation as the paper does it (§II-B.4): the translation by grid searches parallel to
each detector, the axial rotation by a linear search, on plain cost callables ``T -> float``.
Poses are 4x4 ``T_carm_transducer`` (mm); the steps are in docs/pose-estimation.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from histostudy.geometry import make_transform
from histostudy.imaging import View
from histostudy.transducer import pose_facing

__all__ = ["COARSE_GRID", "FINE_GRID", "GridSpec", "InitResult", "MEDIUM_GRID", "PAPER_AXIAL_SEEDS_DEG",
           "ROBUST_AXIAL_SEEDS_DEG", "axial_minima", "axial_search", "grid_offsets", "grid_search", "initialise_pose",
           "rotation_from_direction", "translation_costs"]

#: A cost: ``T_carm_transducer`` (4x4) -> eq. 3's value (px²).
CostFn = Callable[[np.ndarray], float]


def rotation_from_direction(direction, axial_angle_rad: float = 0.0) -> np.ndarray:
    """Rotation of the transducer whose centre-to-focus direction (its ``-z``) is ``direction``,
    turned by ``axial_angle_rad`` about its axis (the convention of
    :func:`histostudy.transducer.pose_facing`)."""
    return pose_facing(direction, (0.0, 0.0, 0.0), axial_angle_rad)[:3, :3]


@dataclass(frozen=True)
class GridSpec:
    """A rectangular grid on a detector-parallel plane: ``n_u x n_v`` points ``step_mm`` apart."""

    n_u: int
    n_v: int
    step_mm: float

    def __post_init__(self):
        if self.n_u < 1 or self.n_v < 1 or not (np.isfinite(self.step_mm) and self.step_mm > 0):
            raise ValueError(f"GridSpec needs n_u, n_v >= 1 and step_mm > 0, got {self}")


#: The paper's coarse grid: 130 points, 3 cm apart, about 40 x 30 cm.
COARSE_GRID = GridSpec(13, 10, 30.0)
#: The paper's fine grid: 49 points, 0.5 cm apart, 3 x 3 cm.
FINE_GRID = GridSpec(7, 7, 5.0)
#: Beyond the paper: a 7 x 7 grid at 1 cm between the coarse and the fine grid. The fine grid
#: reaches +-1.5 cm, half a coarse step; when the coarse grid's optimum is the neighbour of the
#: right point (its scores are nearly flat 3 cm off) this one still brings it back.
MEDIUM_GRID = GridSpec(7, 7, 10.0)
#: The paper's coarse grid runs at one axial angle.
PAPER_AXIAL_SEEDS_DEG = (0.0,)
#: Beyond the paper: coarse grids from four axial angles (the aperture has 180 deg symmetry).
ROBUST_AXIAL_SEEDS_DEG = (0.0, 45.0, 90.0, 135.0)


def grid_offsets(view: View, grid: GridSpec) -> np.ndarray:
    """``(n_u * n_v, 3)`` world offsets of a grid centred on 0, spanned by the view's detector axes."""
    axes = view.detector_axes
    iu = (np.arange(grid.n_u) - (grid.n_u - 1) / 2.0) * grid.step_mm
    iv = (np.arange(grid.n_v) - (grid.n_v - 1) / 2.0) * grid.step_mm
    uu, vv = np.meshgrid(iu, iv, indexing="ij")
    return uu.reshape(-1, 1) * axes[0] + vv.reshape(-1, 1) * axes[1]


def translation_costs(cost: CostFn, R: np.ndarray, translations_mm: np.ndarray) -> np.ndarray:
    """``cost`` at the poses ``(R, t)`` for each row of ``translations_mm``; in one call where the
    cost offers it (:meth:`histostudy.pose.cost.PoseCost.costs_at_translations`)."""
    batch = getattr(cost, "costs_at_translations", None)
    if batch is not None:
        return np.asarray(batch(R, translations_mm), dtype=np.float64)
    return np.array([cost(make_transform(R, p)) for p in translations_mm], dtype=np.float64)


def grid_search(cost: CostFn, R: np.ndarray, centre_mm, view: View, grid: GridSpec) -> tuple[np.ndarray, float, int]:
    """Best focal point on ``grid`` around ``centre_mm`` in ``view``'s detector plane.

    Returns ``(best_point_mm, best_cost, n_evaluations)``.
    """
    centre = np.asarray(centre_mm, dtype=np.float64).reshape(3)
    candidates = centre + grid_offsets(view, grid)
    costs = translation_costs(cost, R, candidates)
    best = int(np.argmin(costs))
    return candidates[best], float(costs[best]), len(candidates)


def axial_search(cost: CostFn, direction, focal_point_mm, n_angles: int = 72,
                 range_rad: float = np.pi) -> tuple[np.ndarray, float, float, int]:
    """Best axial rotation among ``n_angles`` equally spaced angles in ``[0, range_rad)``.

    Returns ``(R, angle_rad, best_cost, n_evaluations)``.
    """
    angles, costs = _axial_costs(cost, direction, focal_point_mm, n_angles, range_rad)
    best = int(np.argmin(costs))
    return rotation_from_direction(direction, angles[best]), float(angles[best]), float(costs[best]), n_angles


def axial_minima(cost: CostFn, direction, focal_point_mm, n_angles: int = 72, range_rad: float = np.pi,
                 count: int = 3) -> tuple[list[tuple[float, float]], int]:
    """The ``count`` lowest local minima ``(angle_rad, cost)`` of the axial cost curve (circular).

    Returns the minima, best first, and the number of evaluations.
    """
    angles, costs = _axial_costs(cost, direction, focal_point_mm, n_angles, range_rad)
    c = np.asarray(costs)
    is_min = (c <= np.roll(c, 1)) & (c <= np.roll(c, -1))
    order = [i for i in np.argsort(c) if is_min[i]][:max(1, count)]
    return [(float(angles[i]), float(c[i])) for i in order], n_angles


def _axial_costs(cost, direction, focal_point_mm, n_angles, range_rad):
    if n_angles < 1:
        raise ValueError(f"n_angles must be >= 1, got {n_angles!r}")
    angles = np.arange(n_angles) * (range_rad / n_angles)
    t = np.asarray(focal_point_mm, dtype=np.float64)
    return angles, [cost(make_transform(rotation_from_direction(direction, a), t)) for a in angles]


@dataclass
class InitResult:
    """The initial pose and how it was found."""

    T_carm_transducer: np.ndarray
    direction: np.ndarray
    axial_angle_rad: float
    cost: float
    n_evaluations: int
    stages: dict = field(default_factory=dict)
    hypotheses: list = field(default_factory=list)


def initialise_pose(direction, views: Sequence[View], view_costs: Sequence[CostFn], joint_cost: CostFn, *,
                    centre_mm=(0.0, 0.0, 0.0), coarse: GridSpec = COARSE_GRID, fine: GridSpec = FINE_GRID,
                    n_axial: int = 72, axial_seeds_deg: Sequence[float] = PAPER_AXIAL_SEEDS_DEG,
                    fine_after_axial: bool = False, n_hypotheses: int = 1, medium: GridSpec | None = None,
                    coarse_scorings: Sequence[tuple[Sequence[CostFn], CostFn]] | None = None,
                    coarse_candidates: int = 1,
                    polish: Callable[[np.ndarray], tuple[np.ndarray, float]] | None = None,
                    depth_search_mm: float = 150.0,
                    seeded: Callable[[np.ndarray], Sequence[tuple[float, np.ndarray]]] | None = None) -> InitResult:
    """Steps 2 and 3 of §II-B.4 for a given direction (step 1's output).

    The paper runs the coarse grids at one (arbitrary) axial angle, then the fine grids, then the
    axial search: ``axial_seeds_deg=(0,)``, ``fine_after_axial=False``. Two optional extensions,
    used by :func:`histostudy.pose.estimate_pose` by default (:data:`ROBUST_AXIAL_SEEDS_DEG`):
    an optional ``medium`` grid between the coarse and the fine one (:data:`MEDIUM_GRID`);
    ``coarse_scorings`` — pairs ``(view_costs, joint_cost)`` — score the coarse grids and their
    axial seeds instead of ``view_costs`` / ``joint_cost``, each scoring proposing its own best
    chains (e.g. distances truncated at about a coarse step, with two costs for points off the
    detector: 3 cm off every point is beyond a narrow truncation and the coarse scores are nearly
    flat, and which off-detector cost ranks the true region first depends on how much of the
    transducer the views see); the chains are then compared on ``joint_cost`` after the
    medium and fine grids;
    ``coarse_candidates > 1`` follows that many of the first view's best coarse points (and
    keeps that many joint chains through the medium and fine grids: neighbouring coarse points
    score alike when the true point lies between them);
    the coarse grids are run from several axial angles and the seed whose grid optimum scores
    lowest on ``joint_cost`` is kept — an elliptical aperture seen at a wrong axial angle pulls
    the coarse optimum off by centimetres when much of the transducer is outside the detector —
    and the fine grids are repeated once the axial angle is known. With ``n_hypotheses > 1`` the
    lowest local minima of the axial cost curve are each carried on (fine grids, then ``polish``,
    a local refinement ``T -> (T, cost)``) and the one with the lowest polished cost is returned;
    the quadrant gaps make the axial curve multi-modal when part of the transducer is hidden.
    ``seeded`` (``direction -> [(axial_deg, translation_mm), ...]``, e.g. from
    :func:`~.silhouette.silhouette_candidates`) proposes more chains that start at those poses instead of a
    coarse-grid point and compete with the coarse chains after the medium and fine grids.

    With a single view the depth along its beam is not seen by the grid; a line search along the
    beam (±``depth_search_mm``, 10 mm then 2 mm steps) scored by the magnification follows.
    """
    views = list(views)
    if len(views) != len(view_costs) or not views:
        raise ValueError(f"views and view_costs must be non-empty and of equal length, "
                         f"got {len(views)} and {len(view_costs)}")
    seeds = [float(a) for a in axial_seeds_deg]
    if not seeds:
        raise ValueError("axial_seeds_deg must hold at least one angle")
    centre = np.asarray(centre_mm, dtype=np.float64).reshape(3)
    scorings = [(list(view_costs), joint_cost)] if coarse_scorings is None else [
        (list(v), j) for v, j in coarse_scorings]
    for v, _ in scorings:
        if len(v) != len(views):
            raise ValueError(f"each coarse scoring must hold one cost per view ({len(views)}), got {len(v)}")
    search = _Search(views, list(view_costs), joint_cost)
    chains = search.coarse_chains(direction, scorings, seeds, centre, coarse, coarse_candidates)
    if seeded is not None:
        chains += search.seeded_chains(direction, seeded)
    hypotheses = []
    for index, chain in enumerate(search.carried_chains(chains, medium, fine)):
        suffix = "" if index == 0 else f"_{chain[2]}"
        if len(views) == 1:
            chain = search.depth_search(chain, depth_search_mm, suffix)
        hypotheses += search.axial_hypotheses(direction, chain[4], suffix, n_axial, n_hypotheses,
                                              fine if fine_after_axial else None, polish)
    T, c, angle = min(hypotheses, key=lambda h: h[1])
    search.stages["axial"] = {"angle_rad": angle, "cost": c}
    return InitResult(T, np.asarray(direction, float), angle, c, search.n_eval, search.stages,
                      hypotheses=[(h[0], h[1]) for h in hypotheses])


#: A chain of the search: ``(joint cost, axial seed (deg), rank label, R, focal point (mm))``.
_Chain = tuple


class _Search:
    """The searches of one :func:`initialise_pose` call on its views and costs, counting the cost
    evaluations (:attr:`n_eval`) and recording each stage's optimum (:attr:`stages`)."""

    def __init__(self, views: list, view_costs: list, joint_cost: CostFn):
        self.views, self.view_costs, self.joint_cost = views, view_costs, joint_cost
        self.n_eval = 0
        self.stages: dict[str, Any] = {}

    def grids(self, R, point, spec: GridSpec, label: str) -> np.ndarray:
        """Each view's grid search in turn, the next centred on the last's optimum."""
        for i, (view, cost) in enumerate(zip(self.views, self.view_costs)):
            point, c, n = grid_search(cost, R, point, view, spec)
            self.n_eval += n
            self.stages[f"{label}_{view.name or i}"] = {"point_mm": point.copy(), "cost": c}
        return point

    def coarse_chains(self, direction, scorings, seeds, centre, coarse: GridSpec, n_candidates: int) -> list[_Chain]:
        """Coarse stage, per scoring and axial seed: the first view's grid keeps its ``n_candidates``
        best points, each followed through the other views' grids and scored jointly; each
        scoring's best chains go on."""
        views, chains = self.views, []
        for s_index, (coarse_view_costs, coarse_joint_cost) in enumerate(scorings):
            scored = []
            for seed in seeds:
                R = rotation_from_direction(direction, np.deg2rad(seed))
                firsts = centre + grid_offsets(views[0], coarse)
                scores = translation_costs(coarse_view_costs[0], R, firsts)
                self.n_eval += len(firsts)
                order = np.argsort(scores, kind="stable")[:max(1, n_candidates)]
                self.stages[f"coarse_grid_s{s_index}_seed{seed:g}_{views[0].name or 0}"] = {
                    "point_mm": firsts[order[0]].copy(), "cost": float(scores[order[0]])}
                for rank, j in enumerate(order):
                    point = firsts[j]
                    for i in range(1, len(views)):
                        point, c, n = grid_search(coarse_view_costs[i], R, point, views[i], coarse)
                        self.n_eval += n
                    scored.append((float(coarse_joint_cost(make_transform(R, point))), seed, f"s{s_index}_r{rank}", R,
                                   point))
                    self.n_eval += 1
            scored.sort(key=lambda c: c[0])
            chains.extend(scored[:max(1, n_candidates)])
        return chains

    def seeded_chains(self, direction, seeded) -> list[_Chain]:
        """The chains that start at the poses ``seeded(direction)`` proposes."""
        chains = []
        for rank, (angle, point) in enumerate(seeded(direction)):
            R = rotation_from_direction(direction, np.deg2rad(angle))
            point = np.asarray(point, dtype=np.float64).reshape(3)
            self.stages[f"seeded_{rank}"] = {"axial_deg": float(angle), "point_mm": point.copy()}
            chains.append((float(self.joint_cost(make_transform(R, point))), float(angle), f"seeded{rank}", R, point))
            self.n_eval += 1
        return chains

    def carried_chains(self, chains: list[_Chain], medium: GridSpec | None, fine: GridSpec) -> list[_Chain]:
        """Medium and fine grids for the chains; the lowest joint cost after them goes on, with the
        best seeded chain beside it where that lies more than a fine step away."""
        # At the fine grid's end the truncated cost still compares poses a centimetre and an axial
        # angle away from their optimum, and a wrong region can win there that loses after the
        # axial search and the polish (measured on notebook 04's robustness failures).
        finished = []
        for _score, seed, rank, R, point in chains:
            label = f"seed{seed:g}_{rank}"
            if medium is not None:
                point = self.grids(R, point, medium, f"medium_grid_{label}")
            point = self.grids(R, point, fine, f"fine_grid_{label}")
            finished.append((float(self.joint_cost(make_transform(R, point))), seed, rank, R, point))
            self.n_eval += 1
        finished.sort(key=lambda f: f[0])
        carried = [finished[0]]
        seeded_chains = [f for f in finished if f[2].startswith("seeded")]
        if seeded_chains and all(np.linalg.norm(seeded_chains[0][4] - f[4]) > fine.step_mm for f in carried):
            carried.append(seeded_chains[0])
        self.stages["axial_seed_deg"] = carried[0][1]
        return carried

    def depth_search(self, chain: _Chain, depth_search_mm: float, suffix: str) -> _Chain:
        """With a single view: the line search along its beam (10 mm, then 2 mm steps) that the
        grid does not see, scored by the magnification."""
        score, seed, rank, R, point = chain
        beam = self.views[0].detector_axes[2]
        for step in (10.0, 2.0):
            span = depth_search_mm if step == 10.0 else 10.0
            offsets = np.arange(-span, span + step / 2, step)
            costs = translation_costs(self.view_costs[0], R, point + offsets[:, None] * beam)
            point = point + offsets[int(np.argmin(costs))] * beam
            self.n_eval += len(offsets)
        self.stages["depth_search" + suffix] = {"point_mm": point.copy()}
        return score, seed, rank, R, point

    def axial_hypotheses(self, direction, point, suffix: str, n_axial: int, n_hypotheses: int,
                         fine_after: GridSpec | None, polish) -> list[tuple[np.ndarray, float, float]]:
        """``(T, cost, angle_rad)`` of each of the ``n_hypotheses`` lowest axial minima at ``point``,
        after the fine grids again (``fine_after``) and ``polish`` where given."""
        minima, n = axial_minima(self.joint_cost, direction, point, n_angles=n_axial, count=n_hypotheses)
        self.n_eval += n
        self.stages["axial_minima" + suffix] = [{"angle_rad": a, "cost": c} for a, c in minima]
        hypotheses = []
        for angle, c in minima:
            R = rotation_from_direction(direction, angle)
            p = point if fine_after is None else self.grids(
                R, point, fine_after, f"fine_grid_after_axial_{np.rad2deg(angle):.1f}{suffix}")
            T = make_transform(R, p)
            if fine_after is not None or polish is not None:
                c = float(self.joint_cost(T))
                self.n_eval += 1
            if polish is not None:
                T, c = polish(T)
            hypotheses.append((T, float(c), angle))
        return hypotheses
