"""The treatment plan (§II-D): discrete focal points filling the treatment zone (C-arm frame, mm), ordered
deepest layer first, serpentine within a layer."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import numpy as np

from histostudy.core import to_jsonable
from histostudy.geometry import check_rotation
from histostudy.imaging import vector3_mm

from .zone import TreatmentZone

__all__ = [
    "STUDY_PLAN_INSET_MM",
    "STUDY_PLAN_SPACING_MM",
    "TreatmentPlan",
    "plan_treatment",
]

#: The studies' plan (notebooks 04 and 05): lattice spacing (LR, TB, depth, mm) and the inset of
#: the ellipsoid the lattice fills (:func:`plan_treatment`). The inset is what makes the union of
#: 3x3x6 mm clouds on this lattice as large as the prescribed sphere, as a clinical planner is
#: calibrated to do: insetting by the cloud's half axes (1.5, 1.5, 3) puts the cloud tips on the
#: sphere, but the scalloped surface between them leaves the segmented zone small (measured with
#: ``histostudy.study.pose.cbct_reference``, 6 experiments of 20-25 mm: radius along
#: depth/TB/LR -1.02/-0.27/-0.45 mm, fitted sphere -0.27 mm); (1, 1, 2) leaves it large
#: (+0.12/+0.23/+0.26, sphere +0.38); (1.25, 1.25, 2.25) gives -0.13/-0.06/-0.23, sphere +0.13.
#: Another spacing or cloud size needs its own inset.
STUDY_PLAN_SPACING_MM = (2.0, 2.0, 3.0)
STUDY_PLAN_INSET_MM = (1.25, 1.25, 2.25)


@dataclass(frozen=True, eq=False)
class TreatmentPlan:
    """Discrete focal points filling the treatment zone, in treatment order (world mm).

    ``points_mm`` (n, 3): focal positions in the C-arm frame. ``lattice_index`` (n, 3): the
    integer lattice coordinates each point came from. ``on_rim`` (n,): the point is a lattice point
    just outside the filled ellipsoid moved onto its surface (so the plan covers the whole zone).
    ``axes``: 3x3 rotation whose columns are the lattice axes in the world frame.
    ``semi_axes_mm``: the filled ellipsoid's semi-axes along ``axes`` (the zone radius minus
    ``inset_mm``). ``spacing_mm`` (3,): lattice spacing along ``axes``.
    """

    centre_mm: np.ndarray
    diameter_mm: float
    spacing_mm: np.ndarray
    pulses_per_point: int
    axes: np.ndarray
    inset_mm: np.ndarray
    semi_axes_mm: np.ndarray
    points_mm: np.ndarray
    lattice_index: np.ndarray
    on_rim: np.ndarray

    def __len__(self) -> int:
        return len(self.points_mm)

    @property
    def covering_radius_mm(self) -> float:
        """Every point of the filled ellipsoid lies within this distance of a plan point: ``|spacing| / 2``."""
        return 0.5 * float(np.linalg.norm(self.spacing_mm))

    def to_dict(self) -> dict:
        """Plain-JSON description of the plan (the journal stores it)."""
        return to_jsonable(
            {
                "centre_mm": self.centre_mm,
                "diameter_mm": self.diameter_mm,
                "spacing_mm": self.spacing_mm,
                "pulses_per_point": self.pulses_per_point,
                "axes": self.axes,
                "inset_mm": self.inset_mm,
                "semi_axes_mm": self.semi_axes_mm,
                "points_mm": self.points_mm,
                "lattice_index": self.lattice_index,
                "on_rim": self.on_rim,
            }
        )

    def fingerprint(self) -> str:
        """SHA-256 of the plan's JSON: a journal only resumes the plan it was written for."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode("utf-8")).hexdigest()


def _project_onto_ellipsoid(p: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Closest points on the ellipsoid ``sum(x_i^2 / a_i^2) = 1`` to points ``p`` outside it.

    The closest point is ``x_i = a_i^2 p_i / (a_i^2 + t)`` with ``t >= 0`` the root of the
    (decreasing) ``sum((a_i p_i / (a_i^2 + t))^2) - 1``, found by bisection. Metric projection onto
    a convex set is 1-Lipschitz, which is what keeps the plan's covering radius (see
    :func:`plan_treatment`).
    """
    a2 = a * a
    lo = np.zeros(len(p))
    hi = np.full(len(p), np.linalg.norm(p, axis=1).max() * a.max() + 1.0)
    for _ in range(100):
        t = 0.5 * (lo + hi)
        g = np.sum((a * p / (a2 + t[:, None])) ** 2, axis=1) - 1.0
        lo = np.where(g > 0, t, lo)
        hi = np.where(g > 0, hi, t)
    t = 0.5 * (lo + hi)
    return a2 * p / (a2 + t[:, None])


def _serpentine_order(ijk: np.ndarray) -> np.ndarray:
    """Order lattice indices layer by layer along axis 2 (ascending), rows along axis 1 alternating
    per layer, points along axis 0 alternating per row: a boustrophedon path whose consecutive
    points are lattice neighbours within a layer."""
    order = []
    row_count = 0
    for li, k in enumerate(np.unique(ijk[:, 2])):
        in_layer = np.nonzero(ijk[:, 2] == k)[0]
        rows = np.unique(ijk[in_layer, 1])
        if li % 2 == 1:
            rows = rows[::-1]
        for j in rows:
            in_row = in_layer[ijk[in_layer, 1] == j]
            in_row = in_row[np.argsort(ijk[in_row, 0], kind="stable")]
            if row_count % 2 == 1:
                in_row = in_row[::-1]
            order.extend(in_row.tolist())
            row_count += 1
    return np.asarray(order, dtype=int)


def plan_treatment(
    zone: TreatmentZone,
    spacing_mm=2.0,
    pulses_per_point: int = 50,
    *,
    axes=None,
    inset_mm=0.0,
) -> TreatmentPlan:
    """The focal points that treat a zone (§II-D): a rectangular lattice clipped to the zone.

    The lattice is centred on the zone centre with its axes along the columns of ``axes``. It fills
    the ellipsoid of semi-axes ``radius - inset_mm``; lattice points outside it whose cell (the box of
    +-spacing/2 around them) meets it are moved onto its surface, so that every point of the ellipsoid
    lies within ``|spacing|/2`` of a plan point and every plan point lies inside it (rim points can be
    closer than ``spacing`` to each other). Order: layer by layer from the most negative lattice z
    (with the transducer's axes: the deepest layer first, so that the residual bubbles of treated
    points never shadow untreated ones), serpentine within each layer.

    Args:
        zone: the :class:`~.zone.TreatmentZone`.
        spacing_mm: the lattice step, mm, > 0: a scalar or (LR, TB, depth)-ordered ``(3,)``.
        pulses_per_point: an integer >= 1 (the paper's "fixed number of histotripsy pulses per focal
            location").
        axes: (3, 3) rotation whose columns are the lattice axes; None for the world axes (pass
            ``T_carm_transducer[:3, :3]`` so that layers are perpendicular to the propagation).
        inset_mm: scalar or ``(3,)``, >= 0, mm: e.g. the bubble cloud's half-size (1.5, 1.5, 3) so
            that the union of clouds, rather than the cloud centres, fills the sphere.

    Returns:
        The :class:`TreatmentPlan` (world mm).

    Raises:
        TypeError: ``zone`` is not a TreatmentZone.
        ValueError: ``spacing_mm``, ``pulses_per_point``, ``axes`` or ``inset_mm`` out of range, or an
            inset that leaves nothing of the zone.
    """
    if not isinstance(zone, TreatmentZone):
        raise TypeError(f"zone must be a histostudy.treatment.zone.TreatmentZone, got {type(zone).__name__}")
    sp = vector3_mm(spacing_mm, "spacing_mm", positive=True)
    if (isinstance(pulses_per_point, bool) or not isinstance(pulses_per_point, (int, np.integer))
            or pulses_per_point < 1):
        raise ValueError(f"pulses_per_point must be an integer >= 1, got {pulses_per_point!r}")
    R = np.eye(3) if axes is None else check_rotation(axes, "axes")
    inset = vector3_mm(inset_mm, "inset_mm")
    if np.any(inset < 0):
        raise ValueError(f"inset_mm must be >= 0 on every axis, got {inset.tolist()}")
    semi = zone.radius_mm - inset
    if np.any(semi <= 0):
        raise ValueError(
            f"inset_mm={inset.tolist()} leaves nothing of a zone of radius {zone.radius_mm} mm: "
            "each inset must be smaller than the radius"
        )
    cover = 0.5 * float(np.linalg.norm(sp))
    n = np.ceil((semi + cover) / sp).astype(int)
    grids = np.meshgrid(*[np.arange(-n[a], n[a] + 1) for a in range(3)], indexing="ij")
    ijk = np.stack([g.ravel() for g in grids], axis=1)
    local = ijk * sp
    q = np.sum((local / semi) ** 2, axis=1)
    inside = q <= 1.0 + 1e-12
    # An outside lattice point is needed only if its cell (the box of +-spacing/2 around it, where
    # the points it is nearest to live) meets the ellipsoid; lattice and ellipsoid share their axes,
    # so the cell's point of least sum(x_i^2 / a_i^2) is 0 clamped to the box, per axis.
    nearest = np.clip(0.0, local - 0.5 * sp, local + 0.5 * sp)
    meets = np.sum((nearest / semi) ** 2, axis=1) <= 1.0 + 1e-12
    outside_idx = np.nonzero(~inside & meets)[0]
    projected = _project_onto_ellipsoid(local[outside_idx], semi) if len(outside_idx) else np.zeros((0, 3))
    keep_idx = np.concatenate([np.nonzero(inside)[0], outside_idx])
    pts_local = np.concatenate([local[inside], projected])
    rim = np.concatenate([np.zeros(inside.sum(), bool), np.ones(len(outside_idx), bool)])
    ijk = ijk[keep_idx]
    order = _serpentine_order(ijk)
    world = zone.centre_mm + pts_local[order] @ R.T
    return TreatmentPlan(
        centre_mm=zone.centre_mm.copy(),
        diameter_mm=zone.diameter_mm,
        spacing_mm=sp,
        pulses_per_point=int(pulses_per_point),
        axes=R,
        inset_mm=inset,
        semi_axes_mm=semi,
        points_mm=world,
        lattice_index=ijk[order],
        on_rim=rim[order],
    )
