"""The verdict of :func:`histostudy.pose.estimate_pose` (beyond the paper): is a pose one the frames
support? The fit per view both ways and the views' agreement (:func:`judge_fit`,
:func:`unexplained_fraction`, :func:`view_disagreement_mm`), run in turn by :class:`PoseJudge`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np

from histostudy.imaging import Frame, View
from histostudy.transducer import Feature, TransducerModel

from .cost import PoseCost
from .init import COARSE_GRID
from .options import PoseConfig
from .refine import refine_levenberg_marquardt
from .truncations import PoseCosts

__all__ = ["PoseJudge", "PoseVerdict", "SingleViewEvidence", "agreement_reasons", "check_unexplained",
           "check_view_agreement", "judge_fit", "single_view_evidence", "unexplained_fraction", "view_disagreement_mm"]


def _view_of(view_or_frame) -> View:
    """The view of a :class:`~histostudy.imaging.Frame` (or of anything with a ``view``), or the view itself."""
    return view_or_frame if isinstance(view_or_frame, View) else view_or_frame.view


def _view_label(view_or_frame, index: int) -> str:
    """The key of a view in the verdict's per-view figures: its name, else its index."""
    return _view_of(view_or_frame).name or str(index)


@dataclass
class PoseVerdict:
    """Whether a pose is plausible, and the figures it was judged on.

    Attributes:
        ok: all checks passed.
        reasons: what failed, in words (empty when ok).
        rms_distance_px: per view, the root of the mean over active classes of the mean squared
            distance of the projected model points to their class (outside points count with the
            constant of eq. 3; each distance capped at :func:`estimate_pose`'s
            ``verdict_truncation_px``).
        inside_fraction: per view, the fraction of model points projecting onto the detector.
            Both are measured on the point subset of the initialisation (``init_points_per_class``).
        focal_offset_mm: distance of the focal point from the search centre.
        unexplained_fraction: per view, the fraction of the segmented pixels (any feature class)
            farther than ``verdict_truncation_px`` (10 px if None) from every projected model
            point: segmented transducer that the pose leaves unexplained.
        class_rms_distance_px: per view, per feature class name (``"transducer"``, ...), the RMS
            distance of that class's model points (capped as ``rms_distance_px``; NaN where the
            view shows none of the class).
        view_disagreement_mm: per view, how far that view's evidence alone would move the focal
            point across its own ray (see :func:`estimate_pose`'s ``max_view_disagreement_mm``);
            empty with one view, or when the pose failed the other checks first.
        view_gain_px2: per view, how much that view's own eq. 3 cost falls from the pose to the
            view's own optimum (px²); measured with ``view_disagreement_mm``.
        view_relative_gain: per view, ``view_gain_px2`` over the cost at the view's own optimum.
    """

    ok: bool
    reasons: list
    rms_distance_px: dict
    inside_fraction: dict
    focal_offset_mm: float
    view_disagreement_mm: dict = field(default_factory=dict)
    class_rms_distance_px: dict = field(default_factory=dict)
    unexplained_fraction: dict = field(default_factory=dict)
    view_gain_px2: dict = field(default_factory=dict)
    view_relative_gain: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SingleViewEvidence:
    """What one view's evidence alone says about a pose (see :func:`single_view_evidence`).

    Attributes:
        move_mm: how far that view's own optimum moves the focal point across the view's ray (mm).
        cost_px2: that view's eq. 3 cost at the pose (px²).
        own_optimum_cost_px2: that view's eq. 3 cost at its own optimum (px²), at most ``cost_px2``.
    """

    move_mm: float
    cost_px2: float
    own_optimum_cost_px2: float

    @property
    def gain_px2(self) -> float:
        """How much the view's cost falls from the pose to its own optimum (px², >= 0)."""
        return max(self.cost_px2 - self.own_optimum_cost_px2, 0.0)

    @property
    def relative_gain(self) -> float:
        """:attr:`gain_px2` over the cost at the view's own optimum (inf where that is 0): a move
        bought with a small relative gain is a flat valley of the view's cost, not a conflict."""
        if self.own_optimum_cost_px2 > 0:
            return self.gain_px2 / self.own_optimum_cost_px2
        return 0.0 if self.gain_px2 == 0 else float("inf")


def single_view_evidence(cost: PoseCost, frames: Sequence[Frame | View], T_carm_transducer, focal_point_mm,
                         *, max_iter: int = 30) -> dict[str, SingleViewEvidence]:
    """Per view, where that view's evidence alone takes the pose, and what the move buys.

    From ``T_carm_transducer``, ``cost.select_views(a)`` (eq. 3 on view ``a`` only) is minimised by
    Levenberg-Marquardt (at most ``max_iter`` iterations). The focal point's displacement, less its
    component along view ``a``'s ray through the focal point (one view does not fix the depth), is
    the move; the view's cost before and after is its price.

    Args:
        cost: the estimate's consistency :class:`~histostudy.pose.cost.PoseCost` (one map per view
            of ``frames``).
        frames: the views (or frames taken with them), in the cost's view order.
        T_carm_transducer: the pose judged (4x4).
        focal_point_mm: the focal point in the transducer frame (mm).
        max_iter: Levenberg-Marquardt iterations per view.

    Returns:
        ``{view name (else index): SingleViewEvidence}``.
    """
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    focal_local = np.asarray(focal_point_mm, dtype=np.float64)
    focal = T[:3, :3] @ focal_local + T[:3, 3]
    out = {}
    for a, f in enumerate(frames):
        one_view = cost.select_views(a)
        relaxed = refine_levenberg_marquardt(one_view, T, max_iter=max_iter)
        move = relaxed.T[:3, :3] @ focal_local + relaxed.T[:3, 3] - focal
        view = _view_of(f)
        ray = view.ray_directions(view.project(focal[None]))[0]
        out[_view_label(f, a)] = SingleViewEvidence(
            move_mm=float(np.linalg.norm(move - (move @ ray) * ray)), cost_px2=float(one_view(T)),
            own_optimum_cost_px2=float(relaxed.cost))
    return out


def view_disagreement_mm(cost: PoseCost, frames: Sequence[Frame | View], T_carm_transducer, focal_point_mm,
                         *, max_iter: int = 30) -> dict:
    """Per view, how far that view's evidence alone moves the focal point across its ray (mm):
    :func:`single_view_evidence`'s ``move_mm``.

    ``focal_point_mm`` is in the transducer frame. :func:`estimate_pose`'s verdict refuses a pose
    where a view's figure exceeds ``max_view_disagreement_mm``.
    """
    return {name: e.move_mm for name, e in single_view_evidence(cost, frames, T_carm_transducer, focal_point_mm,
                                                                max_iter=max_iter).items()}


#: Up to this tolerance (px) :func:`unexplained_fraction` dilates by a disk; beyond it the disk's
#: area makes OpenCV's distance transform the cheaper of the two (both give the same pixels).
_DILATION_MAX_TOLERANCE_PX = 16.0


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _mark_pixels(uvw, image):
    """Sets ``image`` (uint8) to 1 at the pixel of each homogeneous point ``uvw`` (n, 3) in front of the
    source (w > 0) that rounds (half to even) onto the image; one pass, no index arrays."""
    rows, cols = image.shape
    for i in range(uvw.shape[0]):
        w = uvw[i, 2]
        if w > 0:
            u = np.rint(uvw[i, 0] / w)
            v = np.rint(uvw[i, 1] / w)
            if 0 <= u < cols and 0 <= v < rows:
                image[int(v), int(u)] = 1


def _disk(radius_px: float) -> np.ndarray:
    """The uint8 structuring element of the pixel offsets within ``radius_px`` of the centre, with
    the distance rounded to float32 as OpenCV's exact distance transform rounds it."""
    r = int(np.floor(radius_px))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    return (np.sqrt((dx * dx + dy * dy).astype(np.float32)) <= np.float32(radius_px)).astype(np.uint8)


def unexplained_fraction(view, labels: np.ndarray, model: TransducerModel, T_carm_transducer,
                         tolerance_px: float, *, points_mm: np.ndarray | None = None) -> float:
    """The fraction of ``labels``' segmented pixels (any class > 0) farther than ``tolerance_px``
    from every point of ``model`` projected at ``T_carm_transducer`` into ``view`` (NaN when none
    is segmented); the image-to-model counterpart of eq. 3's model-to-image distances. Distances
    are Euclidean, between pixel centres (each projected point rounded to its pixel).

    ``points_mm``: the model's points of every class stacked in its class order (transducer
    frame), when the caller judges many poses of one model and stacks them once."""
    if not (isinstance(tolerance_px, (int, float, np.floating, np.integer)) and np.isfinite(tolerance_px)
            and tolerance_px >= 0):
        raise ValueError(f"tolerance_px must be a finite number >= 0 (pixels), got {tolerance_px!r}")
    labels = np.asarray(labels)
    segmented = labels > 0
    if not segmented.any():
        return float("nan")
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    points = np.vstack([p for p in model.points.values() if len(p)]) if points_mm is None else points_mm
    uvw = np.ascontiguousarray(view.project_homogeneous(points @ T[:3, :3].T + T[:3, 3]))
    near = np.zeros(labels.shape, np.uint8)
    _mark_pixels(uvw, near)
    if tolerance_px <= _DILATION_MAX_TOLERANCE_PX:
        # The pixels within the tolerance of a model pixel: a dilation by the disk of that radius
        # (much cheaper than the distance transform at such tolerances, docs/tracking.md).
        far = cv2.dilate(near, _disk(tolerance_px), borderType=cv2.BORDER_CONSTANT, borderValue=0) == 0
    else:
        far = cv2.distanceTransform(1 - near, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) > tolerance_px
    return np.count_nonzero(far & segmented) / np.count_nonzero(segmented)


def check_unexplained(verdict: PoseVerdict, frames, labels, model, T, limit: float, tolerance_px: float, *,
                      points_mm: np.ndarray | None = None) -> None:
    """Adds each view's :func:`unexplained_fraction` to ``verdict``; fails it where one exceeds ``limit``."""
    for a, (f, lab) in enumerate(zip(frames, labels)):
        name = _view_label(f, a)
        fraction = unexplained_fraction(_view_of(f), lab, model, T, tolerance_px, points_mm=points_mm)
        verdict.unexplained_fraction[name] = fraction
        if np.isfinite(fraction) and fraction > limit:
            verdict.reasons.append(f"view {name!r}: {100 * fraction:.0f}% of the segmented transducer lies over "
                                   f"{tolerance_px:g} px from the posed model (> {100 * limit:g}%)")
    verdict.ok = not verdict.reasons


def agreement_reasons(evidence: dict[str, SingleViewEvidence], limit_mm: float | None, *,
                      min_gain_px2: float | None = None, max_gain_px2: float | None = None) -> list[str]:
    """Why the views' :func:`single_view_evidence` refuses a pose (empty: it does not).

    A view fails the pose where its move exceeds ``limit_mm`` (None: no bound) while its gain is at
    least ``min_gain_px2`` (None: any gain), or where its gain exceeds ``max_gain_px2`` (None: no
    bound); see :class:`~.options.PoseConfig`'s ``max_view_disagreement_mm``, ``min_view_gain_px2``
    and ``max_view_gain_px2``.

    Args:
        evidence: per view name, what that view alone says (:class:`SingleViewEvidence`).
        limit_mm: the largest move across a view's ray (mm).
        min_gain_px2: the least gain (px²) that makes a long move count.
        max_gain_px2: the largest gain (px²) a view may find, whatever its move.

    Returns:
        One sentence per failed bound and view.
    """
    reasons = []
    for name, e in evidence.items():
        if limit_mm is not None and not e.move_mm <= limit_mm and (min_gain_px2 is None
                                                                   or not e.gain_px2 < min_gain_px2):
            bought = "" if min_gain_px2 is None else f", gaining {e.gain_px2:.3f} px² (>= {min_gain_px2} px²)"
            reasons.append(f"view {name!r} alone moves the focal point {e.move_mm:.2f} mm across its ray "
                           f"(> {limit_mm} mm){bought}: the views disagree on the pose")
        if max_gain_px2 is not None and not e.gain_px2 <= max_gain_px2:
            reasons.append(f"view {name!r} alone lowers its cost by {e.gain_px2:.3f} px² (> {max_gain_px2} "
                           f"px²), moving the focal point {e.move_mm:.2f} mm: the views disagree on the pose")
    return reasons


def check_view_agreement(verdict: PoseVerdict, cost: PoseCost, frames, T, focal_point_mm, limit_mm: float | None, *,
                         min_gain_px2: float | None = None, max_gain_px2: float | None = None) -> None:
    """Adds each view's :func:`single_view_evidence` to ``verdict`` (``view_disagreement_mm``,
    ``view_gain_px2``, ``view_relative_gain``) and fails it for :func:`agreement_reasons`."""
    evidence = single_view_evidence(cost, frames, T, focal_point_mm)
    verdict.view_disagreement_mm = {name: e.move_mm for name, e in evidence.items()}
    verdict.view_gain_px2 = {name: e.gain_px2 for name, e in evidence.items()}
    verdict.view_relative_gain = {name: e.relative_gain for name, e in evidence.items()}
    verdict.reasons += agreement_reasons(evidence, limit_mm, min_gain_px2=min_gain_px2, max_gain_px2=max_gain_px2)
    verdict.ok = not verdict.reasons


def judge_fit(cost: PoseCost, frames: Sequence[Frame | View], T, centre, max_rms_px: float, min_inside: float,
              max_body_rms_px: float | None = None) -> PoseVerdict:
    """The verdict's first checks of pose ``T`` (see :func:`~histostudy.pose.estimate_pose`):
    per view the RMS distance over the active classes (``cost``'s capped distances), the element
    body's RMS distance, the fraction of model points on the detector, and the focal point's
    distance from the search ``centre`` against the coarse grid's reach."""
    reasons = []
    terms = cost.terms(T)
    lam = np.array([cost.class_weights[k] for k in cost.classes])
    rms, inside, class_rms = {}, {}, {}
    all_points = np.vstack([cost.points[k] for k in cost.classes])
    world = all_points @ T[:3, :3].T + T[:3, 3]
    for a, f in enumerate(frames):
        name = _view_label(f, a)
        active = cost.active[a] & (lam > 0)
        per_class = terms[a, active] / lam[active]
        rms[name] = float(np.sqrt(per_class.mean())) if per_class.size else float("inf")
        with np.errstate(divide="ignore", invalid="ignore"):
            class_rms[name] = {Feature(k).name.lower(): (float(np.sqrt(terms[a, s] / lam[s]))
                                                         if cost.active[a][s] and lam[s] > 0 else float("nan"))
                               for s, k in enumerate(cost.classes)}
        body = class_rms[name].get(Feature.TRANSDUCER.name.lower(), float("nan"))
        if max_body_rms_px is not None and np.isfinite(body) and body > max_body_rms_px:
            reasons.append(f"view {name!r}: the element body's RMS distance {body:.2f} px > {max_body_rms_px} px")
        view = _view_of(f)
        uvw = view.project_homogeneous(world)
        with np.errstate(divide="ignore", invalid="ignore"):
            px = uvw[:, :2] / uvw[:, 2:3]
        inside[name] = float(np.mean((uvw[:, 2] > 0) & view.in_image(px)))
        if not np.isfinite(rms[name]) or rms[name] > max_rms_px:
            reasons.append(f"view {name!r}: RMS distance {rms[name]:.2f} px > {max_rms_px} px")
        if inside[name] < min_inside:
            reasons.append(f"view {name!r}: only {100 * inside[name]:.1f}% of the model projects onto the detector")
    offset = float(np.linalg.norm(T[:3, 3] - np.asarray(centre, dtype=np.float64)))
    reach = 0.5 * np.hypot(COARSE_GRID.n_u, COARSE_GRID.n_v) * COARSE_GRID.step_mm + 50.0
    if offset > reach:
        reasons.append(f"focal point {offset:.0f} mm from the search centre, beyond the search region ({reach:.0f} mm)")
    return PoseVerdict(ok=not reasons, reasons=reasons, rms_distance_px=rms, inside_fraction=inside,
                       focal_offset_mm=offset, class_rms_distance_px=class_rms)


class PoseJudge:
    """The verdict stage: ``judge(T) -> PoseVerdict`` of a pose ``T`` (4x4 ``T_carm_transducer``).

    :func:`judge_fit` on ``costs.verdict`` (the point subset: the thresholds are coarse, pixels
    and percent, and it judges as well as the whole model for a fraction of the time), then
    :func:`check_unexplained` where ``max_unexplained_fraction`` is set, then, for a pose that
    passed and two or more views, :func:`check_view_agreement` on ``costs.consistency``.

    Args:
        costs: the estimate's :class:`~.truncations.PoseCosts`.
        views: the views of the labels (or frames taken with them).
        labels: each view's label image (what the unexplained-segmentation check reads).
        model: the digital model (its focal point, and its points for that check).
        options: the thresholds, pixel ones in the labels' pixels.
        label_scale: label pixels per detector pixel; scales only the fixed 10 px tolerance of the
            unexplained check used where ``verdict_truncation_px`` is None.
        unexplained_points_mm: the model points that check projects (default: all of them).
    """

    def __init__(self, costs: PoseCosts, views: Sequence[View | Frame], labels: Sequence[np.ndarray],
                 model: TransducerModel, options: PoseConfig, *, label_scale: float = 1.0,
                 unexplained_points_mm: np.ndarray | None = None):
        self.costs, self.views, self.labels, self.model, self.options = costs, list(views), list(labels), model, options
        self.label_scale = label_scale
        self.check_agreement = len(self.views) > 1 and (options.max_view_disagreement_mm is not None
                                                         or options.max_view_gain_px2 is not None)
        if unexplained_points_mm is None and options.max_unexplained_fraction is not None:
            # Stacked once here: every verdict projects all of the model's points.
            unexplained_points_mm = np.vstack([p for p in model.points.values() if len(p)])
        self.unexplained_points_mm = unexplained_points_mm

    def __call__(self, T: np.ndarray) -> PoseVerdict:
        opts = self.options
        occlusion_aware = opts.distance_maps == "occlusion_aware"
        verdict = judge_fit(self.costs.verdict, self.views, T, opts.search_centre_mm, opts.max_rms_px,
                            opts.min_inside_fraction, opts.max_body_rms_px if occlusion_aware else None)
        if opts.max_unexplained_fraction is not None:
            tolerance = 10.0 * self.label_scale if opts.verdict_truncation_px is None else opts.verdict_truncation_px
            check_unexplained(verdict, self.views, self.labels, self.model, T, opts.max_unexplained_fraction,
                              tolerance, points_mm=self.unexplained_points_mm)
        if verdict.ok and self.check_agreement:
            check_view_agreement(verdict, self.costs.consistency, self.views, T, self.model.focal_point_mm,
                                 opts.max_view_disagreement_mm, min_gain_px2=opts.min_view_gain_px2,
                                 max_gain_px2=opts.max_view_gain_px2)
        return verdict
