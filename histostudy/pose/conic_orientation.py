"""A geometric orientation initialiser beside the paper's VGG19 (§II-B.4): the transducer axis from
its inner boundary's ellipse (:class:`ConicOrientation`), the VGG19 as fallback where a view shows
no usable ellipse, and the pipeline's default orientation stage (:func:`default_orientation`).
Directions are world (C-arm) unit vectors from the transducer centre to its focal point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from histostudy.core import stage
from histostudy.geometry import rotation_about_axis
from histostudy.imaging import Frame, View
from histostudy.learning import (
    OracleSegmenter,
    OrientationSource,
    Segmenter,
    angles_from_direction,
    default_segmenter,
    default_vgg19,
    direction_candidates,
)
from histostudy.transducer import Feature, TransducerModel, TransducerSpec, pose_facing

from .conic import CirclePose, EllipseFit, circle_poses_from_conic, fit_ellipse_ransac

__all__ = ["ConicFit", "ConicOrientation", "default_orientation"]

# Model points per class of the per-view fits (1 mm grid, subsampled).
_POINTS_PER_CLASS = 1500
# Axial angles of the per-view fit: the aperture is symmetric under a half turn.
_AXIAL_DEG = tuple(range(0, 180, 15))
# Distance cap (px) of the axial search: as the pose initialisation's search cost.
_SEARCH_CAP_PX = 30.0


@dataclass(frozen=True)
class ConicFit:
    """What :meth:`ConicOrientation.fit` found in one view.

    Attributes:
        ellipse: the robust ellipse fit of the inner-boundary pixels.
        circles: the two 3-D circle poses the ellipse allows.
        directions: ``(2, 3)`` world focal directions, one per circle pose (sign resolved).
        sign_scores: per circle pose, the fit score (px², lower is better; :meth:`ConicOrientation.
            _fit_circle_pose`) of the chosen sign of the axis and of the other one.
    """

    ellipse: EllipseFit
    circles: tuple
    directions: np.ndarray
    sign_scores: tuple


@dataclass(frozen=True, eq=False)
class ConicOrientation:
    """Transducer orientation from the ellipse of the inner boundary, an :class:`OrientationSource`.

    Args:
        segmenter: makes the labels for :meth:`estimate` (a frame in, a label image out); None:
            the shipped U-Net (:func:`histostudy.learning.default_segmenter`), or the frame's
            reference labels when it has them and no U-Net is shipped. :func:`histostudy.pose.
            estimate_pose` passes its own labels through :meth:`direction_candidates_from_labels`
            and never segments twice.
        fallback: the orientation source for views without a usable ellipse (None: such a view
            raises ``ValueError`` in :meth:`estimate`).
        spec: the transducer's geometry (cutout radius, inner band width, cap radius).
        min_pixels: fewest inner-boundary pixels worth fitting.
        min_inlier_fraction: fewest of them the ellipse must explain (RANSAC inliers); the shipped
            U-Net's inner boundary is a band wider than the reference's, so fewer of its pixels
            lie within the tolerance of any ellipse.
        tolerance_px: RANSAC inlier distance (px, at the frame's resolution); None: from the inner
            band's width as the view images it at the isocentre (the band's pixels lie up to half
            its width from the ellipse through its middle), plus 2 px.
        min_minor_axis_px: a thinner ellipse is a nearly edge-on view, whose axis the conic cannot
            tell; None: three times the inlier tolerance (about 28 px, an elevation near 75 deg
            for the inner boundary at the paper's geometry). On the shipped U-Net's labels of
            notebook 03's frames, 4 of 10 fits thinner than that were off by > 90 deg.
        ransac_iterations: RANSAC draws of the ellipse fit.

    Raises:
        TypeError: ``spec`` is not a ``TransducerSpec``, or ``fallback`` not an orientation source.
        ValueError: ``min_inlier_fraction`` not in [0, 1), a pixel threshold not finite and > 0, or
            ``min_pixels`` / ``ransac_iterations`` not an integer >= 6.
    """

    segmenter: Segmenter | None = field(default=None, repr=False)
    fallback: OrientationSource | None = field(default=None, repr=False)
    spec: TransducerSpec = field(default_factory=TransducerSpec)
    min_pixels: int = 150
    min_inlier_fraction: float = 0.35
    tolerance_px: float | None = None
    min_minor_axis_px: float | None = None
    ransac_iterations: int = 200

    def __post_init__(self):
        if not isinstance(self.spec, TransducerSpec):
            raise TypeError(f"spec must be a TransducerSpec, got {type(self.spec).__name__}")
        if self.fallback is not None and not isinstance(self.fallback, OrientationSource):
            raise TypeError(f"fallback must be an OrientationSource or None, got {type(self.fallback).__name__}")
        for name in ("min_inlier_fraction",):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0 <= value < 1):
                raise ValueError(f"{name} must be a number in [0, 1), got {value!r}")
        for name in ("tolerance_px", "min_minor_axis_px"):
            value = getattr(self, name)
            if value is None:
                continue
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        for name in ("min_pixels", "ransac_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 6:
                raise ValueError(f"{name} must be an integer >= 6, got {value!r}")

    @property
    def manifest(self) -> dict | None:
        """The manifest of the fallback's network (the learned part of this stage, e.g. the VGG19),
        so that :data:`histostudy.pose.LEARNED_STAGE_REQUIREMENTS` judge it; None without one."""
        return getattr(self.fallback, "manifest", None)

    # --- geometry of the transducer ----------------------------------------------------------

    @property
    def circle_radius_mm(self) -> float:
        """Radius of the circle the inner-boundary pixels trace: the middle of the inner band."""
        return self.spec.cutout_diameter_mm / 2 + self.spec.inner_band_mm / 2

    @property
    def circle_height_mm(self) -> float:
        """Height of that circle above the focal point along the transducer's +z (on the cap)."""
        return float(np.sqrt(self.spec.radius_mm ** 2 - self.circle_radius_mm ** 2))

    def _tolerance_px(self, view: View) -> float:
        if self.tolerance_px is not None:
            return float(self.tolerance_px)
        e_u = view.detector_axes[0]
        px_per_mm = float(np.linalg.norm(np.diff(view.project(np.array([[0.0, 0.0, 0.0], e_u])), axis=0)))
        return 0.5 * self.spec.inner_band_mm * px_per_mm + 2.0

    def _model_points(self) -> dict:
        """A subset of the digital model's points per class (1 mm grid, <= 1500 per class)."""
        cached = getattr(self, "_points_cache", None)
        if cached is None:
            model = TransducerModel.build(self.spec, spacing_mm=1.0)
            cached = {}
            for k, pts in model.points.items():
                if len(pts):
                    cached[k] = pts[::max(1, len(pts) // _POINTS_PER_CLASS)]
            object.__setattr__(self, "_points_cache", cached)
        return cached

    def _fit_circle_pose(self, circle: CirclePose, sign: float, maps, tolerance_px: float):
        """The pose with this circle and focal direction ``sign * normal``, and its score (px²).

        The axis is first refined by fitting the model's inner boundary (band and wall) to its
        class's distance map, then the axial angle is searched (the whole model, distances capped
        at 30 px as the pose initialisation's search) and the whole model refined from the best
        angle; the score is its mean squared distance capped at ``tolerance_px``. The wrong sign
        puts the elements on the far side of the cutout: seen obliquely they miss the segmented
        ones, seen along the axis their rim lands at the wrong magnification.
        """
        from .cost import PoseCost
        from .refine import refine_levenberg_marquardt

        direction = sign * circle.normal
        T = pose_facing(direction, circle.centre_mm + self.circle_height_mm * direction)
        points = self._model_points()
        inner = PoseCost({Feature.INNER_BOUNDARY: points[Feature.INNER_BOUNDARY]}, [maps],
                         outside_distance_px=tolerance_px, max_distance_px=tolerance_px)
        T = refine_levenberg_marquardt(inner, T, max_iter=30, ftol=1e-4, xtol_mm=1e-2, xtol_rad=1e-4).T
        whole = PoseCost(points, [maps], outside_distance_px=_SEARCH_CAP_PX, max_distance_px=_SEARCH_CAP_PX)
        best_cost, best_T = np.inf, T
        for axial in _AXIAL_DEG:
            Ta = T.copy()
            Ta[:3, :3] = T[:3, :3] @ rotation_about_axis([0.0, 0.0, 1.0], np.deg2rad(axial))
            c = float(whole(Ta))
            if c < best_cost:
                best_cost, best_T = c, Ta
        fine = whole.capped(tolerance_px, outside_distance_px=tolerance_px)
        T = refine_levenberg_marquardt(fine, best_T, max_iter=30, ftol=1e-4, xtol_mm=1e-2, xtol_rad=1e-4).T
        return T, float(fine(T))

    # --- the estimate ---------------------------------------------------------------------------

    @stage("orient")
    def fit(self, labels, view: View, rng: np.random.Generator, maps=None, *, executor=None) -> ConicFit | None:
        """The ellipse of the inner boundary in ``labels`` and the focal directions it gives, or
        None when the view shows no usable ellipse (see the class's thresholds). ``maps``: the
        labels' :class:`~histostudy.pose.distance_maps.DistanceMaps` when already made (else made here).
        ``executor``: a ``concurrent.futures.Executor`` that fits the four (circle, sign) poses
        concurrently (they draw nothing, so the result is the same); None: one after the other."""
        labels = np.asarray(labels)
        if labels.shape != tuple(view.shape):
            raise ValueError(f"labels have shape {labels.shape}, expected the view's {view.shape}")
        rows, cols = np.nonzero(labels == Feature.INNER_BOUNDARY)
        if len(rows) < self.min_pixels:
            return None
        tolerance = self._tolerance_px(view)
        ellipse = fit_ellipse_ransac(np.column_stack([cols, rows]), rng, tolerance_px=tolerance,
                                     iterations=self.ransac_iterations)
        if ellipse is None or ellipse.inlier_fraction < self.min_inlier_fraction:
            return None
        min_minor = 3.0 * tolerance if self.min_minor_axis_px is None else self.min_minor_axis_px
        if ellipse.semi_axes_px[1] < min_minor:
            return None
        try:
            circles = circle_poses_from_conic(ellipse.conic, view, self.circle_radius_mm)
        except ValueError:
            return None
        from .distance_maps import DistanceMaps

        if maps is None:
            maps = DistanceMaps(view, labels, occlusion_aware=True)
        elif not isinstance(maps, DistanceMaps) or maps.view is not view:
            raise ValueError("maps must be the DistanceMaps of these labels in this view")
        cases = [(circle, sign) for circle in circles for sign in (1.0, -1.0)]

        def fit_case(case: tuple[CirclePose, float]):
            circle, sign = case
            return self._fit_circle_pose(circle, sign, maps, tolerance)

        fits = list(map(fit_case, cases) if executor is None else executor.map(fit_case, cases))
        directions, scores = [], []
        for i in range(len(circles)):
            best, other = sorted(fits[2 * i:2 * i + 2], key=lambda f: f[1])
            directions.append(-best[0][:3, 2])
            scores.append((best[1], other[1]))
        return ConicFit(ellipse=ellipse, circles=tuple(circles), directions=np.array(directions),
                        sign_scores=tuple(scores))

    def direction_candidates_from_labels(self, frame: Frame, labels, rng: np.random.Generator,
                                         maps=None) -> np.ndarray:
        """``(2, 3)`` world focal-direction candidates of one view, from its labels (the conic's two
        solutions), or the fallback's eq. 4 pair where the view shows no usable ellipse or the
        fit fails. Raises ``ValueError`` when neither can answer. ``maps`` as in :meth:`fit`."""
        return self._candidates(frame, labels, rng, maps)[0]

    def candidates(self, frame: Frame, rng: np.random.Generator | None = None) -> tuple[np.ndarray, bool]:
        """``((2, 3) world focal-direction candidates, fell_back)`` of one frame, segmenting it with
        :attr:`segmenter`; ``fell_back`` says the fallback source answered (no usable ellipse)."""
        if not isinstance(frame, Frame):
            raise TypeError(f"frame must be a histostudy.imaging.frame.Frame, got {type(frame).__name__}")
        rng = np.random.default_rng(0) if rng is None else rng
        return self._candidates(frame, self._segment(frame, rng), rng)

    def _candidates(self, frame: Frame, labels, rng: np.random.Generator, maps=None) -> tuple[np.ndarray, bool]:
        fit = self.fit(labels, frame.view, rng, maps)
        if fit is not None:
            return fit.directions, False
        if self.fallback is None:
            raise ValueError(f"view {frame.view.name!r}: no usable inner-boundary ellipse and no fallback "
                             f"orientation source")
        azimuth_rad, elevation_rad = self.fallback.estimate(frame, rng)
        return direction_candidates(azimuth_rad, elevation_rad, frame.view), True

    def estimate(self, frame: Frame, rng: np.random.Generator | None = None) -> tuple[float, float]:
        """``(azimuth_rad, elevation_rad)`` of the frame's view (the protocol of
        :class:`~histostudy.learning.orientation.OrientationSource`): the mean of the two candidates, each
        taken on the hemisphere away from the detector."""
        candidates, _ = self.candidates(frame, rng)
        R = frame.view.detector_axes
        canonical = []
        for d in candidates:
            d_det = R @ d
            if d_det[2] > 0:
                d_det[2] = -d_det[2]
            canonical.append(d_det)
        mean = np.sum(canonical, axis=0)
        return angles_from_direction(R.T @ mean, frame.view)

    def _segment(self, frame: Frame, rng: np.random.Generator) -> np.ndarray:
        segmenter = self.segmenter
        if segmenter is None:
            segmenter = default_segmenter()
            if segmenter is None:
                segmenter = OracleSegmenter()
            object.__setattr__(self, "segmenter", segmenter)
        return np.asarray(segmenter.segment(frame, rng), dtype=np.uint8)


def default_orientation(segmenter=None) -> OrientationSource | None:
    """The pipeline's orientation stage (§II-B.4), its learned parts shipped in ``data/models``.

    The geometric initialiser (:class:`ConicOrientation`: the axis from the inner boundary's
    ellipse in the shipped U-Net's labels) with the shipped VGG19 regressor (the paper's §II-B.4
    network) answering for views without a usable ellipse; the VGG19 alone when no U-Net is shipped.
    Measured against the VGG19 alone in notebooks 03 and 04.

    Args:
        segmenter: the U-Net already loaded; None: :func:`histostudy.learning.default_segmenter`.

    Returns:
        The :class:`~histostudy.learning.OrientationSource`; None when the VGG19 is missing or fails
        its check (callers then fall back to :class:`~histostudy.learning.OracleOrientation` and say
        so).
    """
    vgg = default_vgg19()
    if vgg is None:
        return None
    unet = default_segmenter() if segmenter is None else segmenter
    return vgg if unet is None else ConicOrientation(segmenter=unet, fallback=vgg)
