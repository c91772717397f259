"""Histotripsy treatment: the plan of discrete focal points, its execution on the robot, the bubble
clouds and the post-treatment phantom (paper §II-D, §II-D.1, §IV).

§II-D: "the robotic arm was motioned through the planned treatment volume comprised of a plurality
of discrete focal locations and delivered a predetermined fixed number of histotripsy pulses per
focal location"; the excitation makes a 3x3x6 mm bubble cloud. §II-D.1: treatment mixes the
phantom's layers into a medium attenuation. §IV: the bubble cloud sits off the geometric focal
point (manufacturing, aberration).

Frames and units: millimetres; the plan lives in the C-arm (world) frame; the robot is commanded in
its base frame with the TCP at the transducer's focal point, so ``T_base_tcp`` positions the focal
point. The transducer frame has its origin at the geometric focal point and +z towards the
transducer: ultrasound propagates along -z ("depth"); TB = y, LR = x.

Execution keeps a journal (JSON, rewritten atomically after every treated point with
:func:`histostudy.core.io.atomic_write_json`): a treatment interrupted by a robot fault resumes from
the journal — on a fresh connection or a fresh robot — without treating a point twice or skipping
one. A point counts as treated once its journal entry is on disk.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from histostudy.core import atomic_write_json, atomic_write_text, to_jsonable
from histostudy.geometry import check_rigid, check_rotation, make_transform, transform_points
from histostudy.imaging import Volume
from histostudy.imaging.volume import _check_mask, _check_volume, _vec3
from .zone import TreatmentZone

__all__ = [
    "BUBBLE_CLOUD_SIZE_MM",
    "STUDY_PLAN_INSET_MM",
    "STUDY_PLAN_SPACING_MM",
    "JOURNAL_FORMAT",
    "TreatmentPlan",
    "TreatmentRun",
    "bubble_cloud_mask",
    "execute_treatment",
    "load_journal",
    "plan_treatment",
    "post_treatment_phantom",
    "scan_treated_zone",
]

#: Full axes (LR, TB, depth) of the bubble cloud the paper's excitation sequence creates (§II-D), mm.
BUBBLE_CLOUD_SIZE_MM = (3.0, 3.0, 6.0)

#: The studies' plan (notebooks 04 and 05): lattice spacing (LR, TB, depth, mm) and the inset of
#: the ellipsoid the lattice fills (:func:`plan_treatment`). The inset is what makes the union of
#: 3x3x6 mm clouds on this lattice as large as the prescribed sphere, as a clinical planner is
#: calibrated to do: insetting by the cloud's half axes (1.5, 1.5, 3) puts the cloud tips on the
#: sphere, but the scalloped surface between them leaves the segmented zone small (measured with
#: ``histostudy.study.pose_estimation.cbct_reference``, 6 experiments of 20-25 mm: radius along
#: depth/TB/LR -1.02/-0.27/-0.45 mm, fitted sphere -0.27 mm); (1, 1, 2) leaves it large
#: (+0.12/+0.23/+0.26, sphere +0.38); (1.25, 1.25, 2.25) gives -0.13/-0.06/-0.23, sphere +0.13.
#: Another spacing or cloud size needs its own inset.
STUDY_PLAN_SPACING_MM = (2.0, 2.0, 3.0)
STUDY_PLAN_INSET_MM = (1.25, 1.25, 2.25)

JOURNAL_FORMAT = "histostudy.treatment_journal"
JOURNAL_VERSION = 1


# ---------------------------------------------------------------------------------------------
# Plan
# ---------------------------------------------------------------------------------------------


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
    """Plan the focal points that treat ``zone`` (§II-D): a rectangular lattice clipped to the zone.

    The lattice (``spacing_mm``: scalar or (LR, TB, depth)-ordered (3,), mm, > 0) is centred on
    the zone centre with its axes along the columns of ``axes`` (3x3 rotation, default the world
    axes; pass ``T_carm_transducer[:3, :3]`` so that layers are perpendicular to the propagation).
    It fills the ellipsoid of semi-axes ``radius - inset_mm`` (``inset_mm``: scalar or (3,),
    >= 0; e.g. the bubble cloud's half-size (1.5, 1.5, 3) so that the union of clouds, rather than
    the cloud centres, fills the sphere). Lattice points outside it whose cell (the box of
    +-spacing/2 around them) meets it are moved onto its surface (to their closest point on it):
    since the projection
    onto a convex set never increases distances to points inside it, every point of the ellipsoid
    lies within ``|spacing|/2`` of a plan point, and every plan point lies inside the ellipsoid.
    Rim points can be closer than ``spacing`` to each other and to lattice points.

    Order: layer by layer from the most negative lattice z (with the transducer's axes: the
    deepest layer first, so that the residual bubbles of treated points never shadow untreated
    ones), serpentine within each layer. ``pulses_per_point``: integer >= 1 (the paper's "fixed
    number of histotripsy pulses per focal location").
    """
    if not isinstance(zone, TreatmentZone):
        raise TypeError(f"zone must be a histostudy.treatment.zone.TreatmentZone, got {type(zone).__name__}")
    sp = _vec3(spacing_mm, "spacing_mm", positive=True)
    if isinstance(pulses_per_point, bool) or not isinstance(pulses_per_point, (int, np.integer)) or pulses_per_point < 1:
        raise ValueError(f"pulses_per_point must be an integer >= 1, got {pulses_per_point!r}")
    R = np.eye(3) if axes is None else check_rotation(axes, "axes")
    inset = _vec3(inset_mm, "inset_mm")
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


# ---------------------------------------------------------------------------------------------
# Execution with a journal
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TreatmentRun:
    """What the journal holds about a treatment: per treated point (in plan order) the commanded
    and reached ``T_base_tcp`` (n, 4, 4) mm, the pulses delivered, and whether the plan is done.
    ``resumed_at``: the first point treated by the run that returned this (0 for a fresh start)."""

    journal_path: Path
    n_planned: int
    commanded_T_base_tcp: np.ndarray
    reached_T_base_tcp: np.ndarray
    pulses: np.ndarray
    indices: np.ndarray
    completed: bool
    resumed_at: int

    @property
    def n_treated(self) -> int:
        return len(self.indices)

    @classmethod
    def load(cls, journal_path: str | os.PathLike) -> "TreatmentRun":
        """The run recorded in a journal (``resumed_at`` = the number of points it holds)."""
        path = Path(journal_path)
        journal = load_journal(path)
        return _run_from_journal(path, journal, len(journal["points"]))


def _journal_header(plan: TreatmentPlan, T_base_carm: np.ndarray, R_base_tcp: np.ndarray, T_flange_tcp) -> dict:
    return {
        "format": JOURNAL_FORMAT,
        "version": JOURNAL_VERSION,
        "plan_fingerprint": plan.fingerprint(),
        "plan": plan.to_dict(),
        "T_base_carm": T_base_carm,
        "R_base_tcp": R_base_tcp,
        "T_flange_tcp": T_flange_tcp,
        "completed": False,
        "points": [],
    }


def load_journal(path: str | os.PathLike) -> dict:
    """Read and check a treatment journal (format, version, entries in plan order); returns the dict."""
    path = Path(path)
    try:
        journal = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"journal {path} is not valid JSON ({exc}); it was not written by execute_treatment") from exc
    if not isinstance(journal, dict) or journal.get("format") != JOURNAL_FORMAT:
        raise ValueError(f"journal {path} is not a treatment journal (format must be {JOURNAL_FORMAT!r})")
    if journal.get("version") != JOURNAL_VERSION:
        raise ValueError(f"journal {path} has version {journal.get('version')!r}; this code reads version {JOURNAL_VERSION}")
    indices = [p["index"] for p in journal["points"]]
    if indices != list(range(len(indices))):
        raise ValueError(f"journal {path} holds points {indices[:10]}..., not the plan's first points in order")
    return journal


def _run_from_journal(path: Path, journal: dict, resumed_at: int) -> TreatmentRun:
    pts = journal["points"]
    return TreatmentRun(
        journal_path=path,
        n_planned=len(journal["plan"]["points_mm"]),
        commanded_T_base_tcp=np.array([p["commanded_T_base_tcp"] for p in pts], dtype=np.float64).reshape(-1, 4, 4),
        reached_T_base_tcp=np.array([p["reached_T_base_tcp"] for p in pts], dtype=np.float64).reshape(-1, 4, 4),
        pulses=np.array([p["pulses"] for p in pts], dtype=int),
        indices=np.array([p["index"] for p in pts], dtype=int),
        completed=bool(journal["completed"]),
        resumed_at=resumed_at,
    )


def execute_treatment(
    robot,
    plan: TreatmentPlan,
    T_base_carm,
    R_base_tcp,
    journal_path: str | os.PathLike,
    *,
    T_flange_tcp=None,
    speed_mm_s: float = 20.0,
    acceleration_mm_s2: float = 200.0,
    deliver: Callable[[int, int], None] | None = None,
) -> TreatmentRun:
    """Move the focal point through ``plan`` on ``robot`` and treat each point; journal every point.

    ``T_base_carm``: the calibration (C-arm frame into the robot base frame). ``R_base_tcp``: the
    transducer orientation the targeting chose (3x3, base frame), kept for every point: point ``p``
    (world mm) is commanded as ``T_base_tcp = [R_base_tcp | T_base_carm @ p]``, a linear move at
    ``speed_mm_s`` / ``acceleration_mm_s2``. ``T_flange_tcp``: if given, set on the robot first
    (the focal point in the flange frame) and recorded; a resume must use the same.
    ``deliver(index, pulses)``: fires the plan's pulses at the reached point (the therapy
    sub-system; the simulation has nothing to fire, so the default does nothing).

    Journal (``journal_path``, JSON, rewritten atomically after each point): the plan and its
    fingerprint, the calibration, and per treated point its index, the world point, the commanded
    and the reached ``T_base_tcp`` and the pulses. If the journal exists, its plan and calibration
    must match and execution resumes after its last point (a completed journal returns at once).
    A :class:`~histostudy.robot.RobotError` propagates unchanged, with a note saying how far the
    journal got; running again with the same journal resumes. A point counts as treated once its
    entry is on disk: a fault inside ``deliver``, or a crash between its last pulse and the write,
    leaves the point out of the journal and a resume fires it again (the only way a point is
    treated twice). A resumed run moves straight from wherever the arm is to the next point; the
    robot's workspace checks apply, an approach path is the caller's.
    """
    if not isinstance(plan, TreatmentPlan):
        raise TypeError(f"plan must be a TreatmentPlan, got {type(plan).__name__}")
    T_bc = check_rigid(T_base_carm, "T_base_carm")
    R = check_rotation(R_base_tcp, "R_base_tcp")
    T_ft = None if T_flange_tcp is None else check_rigid(T_flange_tcp, "T_flange_tcp")
    if deliver is not None and not callable(deliver):
        raise TypeError(f"deliver must be callable(index, pulses) or None, got {type(deliver).__name__}")
    if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
        raise ValueError(f"speed_mm_s must be finite and > 0, got {speed_mm_s!r}")
    if not (math.isfinite(acceleration_mm_s2) and acceleration_mm_s2 > 0):
        raise ValueError(f"acceleration_mm_s2 must be finite and > 0, got {acceleration_mm_s2!r}")
    path = Path(journal_path)
    header = to_jsonable(_journal_header(plan, T_bc, R, T_ft))
    if path.exists():
        journal = load_journal(path)
        if journal["plan_fingerprint"] != header["plan_fingerprint"]:
            raise ValueError(f"journal {path} belongs to another plan (fingerprint differs); refusing to resume it with this plan")
        for key in ("T_base_carm", "R_base_tcp", "T_flange_tcp"):
            a, b = journal[key], header[key]
            if (a is None) != (b is None) or (a is not None and not np.allclose(a, b, rtol=0, atol=1e-9)):
                raise ValueError(f"journal {path} was written with another {key} ({a!r}); got {b!r}: refusing to resume")
    else:
        journal = header
        atomic_write_json(path, journal)
    start = len(journal["points"])
    if journal["completed"]:
        return _run_from_journal(path, journal, start)

    # The journal is rewritten whole after every point; its entries are serialised once and the
    # file assembled from the cached texts, so a write costs O(file size), not O(entries) of
    # Python-object conversion (a 1000-point plan would otherwise spend minutes in json.dumps).
    head = {k: v for k, v in journal.items() if k not in ("completed", "points")}
    head_text = json.dumps(head, separators=(",", ":"))[:-1]
    entries = [json.dumps(e, separators=(",", ":")) for e in journal["points"]]

    def write(completed: bool) -> None:
        text = f'{head_text},"completed":{"true" if completed else "false"},"points":[\n' + ",\n".join(entries) + "\n]}\n"
        atomic_write_text(path, text)

    if T_ft is not None:
        robot.set_tcp(T_ft)
    targets = transform_points(T_bc, plan.points_mm)
    for i in range(start, len(plan)):
        commanded = make_transform(R, targets[i])
        try:
            reached = np.asarray(robot.move_linear(commanded, speed_mm_s, acceleration_mm_s2), dtype=np.float64)
            if deliver is not None:
                deliver(i, plan.pulses_per_point)
        except Exception as exc:
            exc.add_note(
                f"treatment interrupted at point {i} of {len(plan)}: the journal {path} holds points 0..{i - 1}; "
                "run execute_treatment again with the same journal to resume"
            )
            raise
        entries.append(
            json.dumps(
                {
                    "index": i,
                    "point_carm_mm": plan.points_mm[i].tolist(),
                    "commanded_T_base_tcp": commanded.tolist(),
                    "reached_T_base_tcp": reached.tolist(),
                    "pulses": plan.pulses_per_point,
                },
                separators=(",", ":"),
            )
        )
        write(i == len(plan) - 1)
    if len(plan) == start:  # nothing left (an empty remainder): mark done
        write(True)
    return _run_from_journal(path, load_journal(path), start)


# ---------------------------------------------------------------------------------------------
# Bubble clouds and the post-treatment phantom
# ---------------------------------------------------------------------------------------------


def bubble_cloud_mask(
    volume: Volume,
    T_carm_transducer,
    focal_point_mm=(0.0, 0.0, 0.0),
    offset_mm=(0.0, 0.0, 0.0),
    size_mm=BUBBLE_CLOUD_SIZE_MM,
) -> np.ndarray:
    """Union of the bubble clouds at the given transducer poses, as a bool ``[z, y, x]`` mask.

    ``T_carm_transducer``: (4, 4) or (n, 4, 4) poses of the transducer frame in the C-arm frame
    (the reached poses, converted by the caller with the calibration's ground truth).
    ``focal_point_mm``: the physical transducer's true focal point in the transducer frame;
    ``offset_mm``: the bubble cloud's further offset from it (aberration, manufacturing, §IV),
    transducer frame. Each cloud is an ellipsoid of full axes ``size_mm`` (LR, TB, depth; paper:
    3x3x6 mm, §II-D) along the transducer's x, y, z, centred at ``focal_point_mm + offset_mm``.
    A voxel belongs to a cloud when its centre does.
    """
    volume = _check_volume(volume)
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    if T.ndim == 2:
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"T_carm_transducer must be (4, 4) or (n, 4, 4), got shape {T.shape}")
    for k in range(len(T)):
        check_rigid(T[k], f"T_carm_transducer[{k}]")
    centre_tf = _vec3(focal_point_mm, "focal_point_mm") + _vec3(offset_mm, "offset_mm")
    semi = 0.5 * _vec3(size_mm, "size_mm", positive=True)
    mask = np.zeros(volume.data.shape, dtype=bool)
    reach = float(semi.max())
    n_xyz = np.asarray(volume.shape_xyz)
    x_ax, y_ax, z_ax = volume.axes_mm()
    for k in range(len(T)):
        c = T[k, :3, :3] @ centre_tf + T[k, :3, 3]
        lo = np.maximum(np.ceil((c - reach - volume.origin_mm) / volume.spacing_mm - 1e-9).astype(int), 0)
        hi = np.minimum(np.floor((c + reach - volume.origin_mm) / volume.spacing_mm + 1e-9).astype(int), n_xyz - 1)
        if np.any(hi < lo):
            continue  # this cloud lies outside the volume
        Z, Y, X = np.meshgrid(z_ax[lo[2] : hi[2] + 1], y_ax[lo[1] : hi[1] + 1], x_ax[lo[0] : hi[0] + 1], indexing="ij")
        d = np.stack([X - c[0], Y - c[1], Z - c[2]], axis=-1) @ T[k, :3, :3]  # transducer-frame offsets
        inside = np.sum((d / semi) ** 2, axis=-1) <= 1.0
        mask[lo[2] : hi[2] + 1, lo[1] : hi[1] + 1, lo[0] : hi[0] + 1] |= inside
    return mask


def post_treatment_phantom(phantom: Volume, treated_mask, roi_mask) -> Volume:
    """The phantom after treatment (§II-D.1): inside the treated part of the phantom the layers are
    mixed, so every voxel there takes the mean attenuation of that part of the untreated phantom.

    ``phantom``: the true (noise-free) pre-treatment attenuation, e.g.
    :func:`histostudy.imaging.cbct.phantom_volume`; ``treated_mask``: bool ``[z, y, x]``, e.g. the union
    of bubble clouds (:func:`bubble_cloud_mask`); ``roi_mask``: bool ``[z, y, x]``, the phantom
    (water around it is not mixed in). The mixture's mean weights both materials by their volume
    in the treated region. Pass the result to :func:`histostudy.imaging.cbct.simulate_cbct`.
    """
    phantom = _check_volume(phantom, "phantom")
    treated = _check_mask(treated_mask, phantom, "treated_mask")
    roi = _check_mask(roi_mask, phantom, "roi_mask")
    region = treated & roi
    data = phantom.data.astype(np.float64).copy()
    if region.any():
        data[region] = data[region].mean()
    return phantom.with_data(data)


def scan_treated_zone(phantom: Volume, roi_mask, T_carm_transducer_reached, focal_point_mm, bubble_offset_mm, *,
                      spec, T_carm_phantom, rng: np.random.Generator, blur_sigma_mm: float, noise_sd_hu: float,
                      voxel_mm: float):
    """The post-treatment CBCT of a treatment and its segmented zone (§II-D.1, §II-E.3).

    The chain every study runs after a treatment: bubble clouds at the reached poses
    (:func:`bubble_cloud_mask`; ``T_carm_transducer_reached`` ``(n, 4, 4)``, the physical
    transducer's ``focal_point_mm`` plus ``bubble_offset_mm`` in its frame), the layers mixed there
    (:func:`post_treatment_phantom` inside ``roi_mask``), the CBCT simulated
    (:func:`histostudy.imaging.cbct.simulate_cbct` with ``blur_sigma_mm``, ``noise_sd_hu``, ``voxel_mm``)
    and the zone segmented inside the phantom ``spec`` placed by ``T_carm_phantom``
    (:func:`histostudy.treatment.zone.segment_treatment_zone`). Returns ``(ZoneSegmentation, post-treatment
    CBCT Volume)``.
    """
    from histostudy.imaging import phantom_mask, simulate_cbct
    from .zone import segment_treatment_zone

    treated = bubble_cloud_mask(phantom, T_carm_transducer_reached, focal_point_mm, bubble_offset_mm)
    post = simulate_cbct(post_treatment_phantom(phantom, treated, roi_mask), rng, blur_sigma_mm=blur_sigma_mm,
                         noise_sd_hu=noise_sd_hu, voxel_mm=voxel_mm)
    return segment_treatment_zone(post, phantom_mask(post, spec, T_carm_phantom)), post
