"""The fast warm update of :class:`~._tracker.Tracker` (§II-B.2-3): :class:`RegionEstimator`,
``estimate_pose``'s warm stages on the region where the last pose projects, with a second attempt at
the rescue scale (docs/tracking.md, "The warm path on the region of interest").
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from histostudy.imaging import Frame, View
from histostudy.learning import UNetRunner, keep_largest_component, pool_labels
from histostudy.transducer import TransducerModel, check_label_image

from ..options import PoseConfig
from ..refine import refine_pose
from ..result import PoseEstimationError, PoseResult, result_of_refinement
from ..truncations import pose_costs
from ..verdict import PoseJudge
from ._maps import RegionMaps
from ._options import TrackingConfig, scaled_pose_options
from ._roi import RegionOfInterest, crop_view, region_of_interest

__all__ = ["PreparedRegions", "RegionEstimator", "RegionPlan"]

#: Model points projected to box the region (every n-th point of each class; the margin covers the
#: spacing they leave).
ROI_POINT_STRIDE = 16


@dataclass
class PreparedRegions:
    """What :meth:`RegionEstimator.prepare` made of a frame pair (steps 1-3 of docs/tracking.md's warm path).

    Attributes:
        regions: each view's :class:`~._roi.RegionOfInterest`.
        labels: each region's ``uint8`` labels at the label scale.
        maps: each region's :class:`~histostudy.pose.distance_maps.DistanceMaps` (in the estimator's
            buffers of the slot).
        timings_s: ``segmentation`` and ``distance_maps`` seconds (summed over views).
        seconds: wall seconds of the preparation.
        frames: the frames the regions were cut from (:meth:`RegionEstimator.prepare_rescue`
            segments them again).
    """

    regions: list
    labels: list
    maps: list
    timings_s: dict
    seconds: float
    frames: list | None = None


@dataclass
class RegionPlan:
    """What :meth:`RegionEstimator.plan` decided for a frame pair before its views are segmented.

    Attributes:
        frames: the pair's frames, in the order of the views.
        regions: each view's :class:`~._roi.RegionOfInterest`.
        rngs: each view's Generator, for a segmenter that draws (None for a U-Net).
        buffers: each view's map buffer (:class:`~._maps.RegionMaps`).
        t_start: ``time.perf_counter()`` when the plan was made.
    """

    frames: list
    regions: list
    rngs: list
    buffers: list
    t_start: float


def _subset_indices(n_points: int, n: int | None, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of ``n`` of ``n_points`` points drawn without replacement (all of them where
    ``n`` is None or not below ``n_points``; nothing drawn then)."""
    if n is None or n_points <= n:
        return np.arange(n_points)
    return np.sort(rng.choice(n_points, size=int(n), replace=False))


def _subset(points: np.ndarray, n: int | None, rng: np.random.Generator) -> np.ndarray:
    return points if n is None or len(points) <= n else points[_subset_indices(len(points), n, rng)]


def _tracking_network(network, segmenter) -> UNetRunner:
    """The :class:`UNetRunner` of :attr:`TrackingConfig.network` (a shipped name is loaded, its
    SHA-256 checked); ValueError when it cannot be loaded or the tracker's segmenter is no U-Net."""
    from histostudy.learning import MODELS_DIR

    if not isinstance(segmenter, UNetRunner):
        raise ValueError(f"TrackingConfig.network {network!r} replaces the tracker's U-Net in the warm updates, "
                         f"but the tracker's segmenter is {type(segmenter).__name__}: pass network=None with it")
    if isinstance(network, UNetRunner):
        return network
    path = MODELS_DIR / f"{network}.safetensors"
    try:
        return UNetRunner.load(path)
    except ValueError as exc:
        raise ValueError(f"TrackingConfig.network {network!r}: the weights {str(path)!r} cannot be used ({exc}); "
                         f"expected a U-Net checkpoint in data/models "
                         f"(histostudy train segmentation_tracking)") from None


class RegionEstimator:
    """Warm-started pose estimates on the regions where the last pose projects (§II-B.2-3; docs/tracking.md).

    Args:
        model: the digital model of eq. 3 (points in mm, transducer frame).
        views: the full-frame views, in the order of the frames.
        segmenter: a :class:`~histostudy.learning.UNetRunner` (run at ``TrackingConfig.precision``)
            or any segmenter (``segment(frame, rng)``).
        options: the :class:`PoseConfig` of the estimates (distance maps, caps, verdict).
        tracking: the :class:`TrackingConfig`.
        rng: draws the fixed point subsets once, here.

    Attributes:
        label_scale: label pixels per frame pixel of the regions.
        rescue_scale: the label scale of :meth:`prepare_rescue` (``TrackingConfig.rescue_scale``),
            None where there is no second attempt (not set, or not above ``label_scale``).
        last_regions: the :class:`~._roi.RegionOfInterest` of each view at the last call.

    Raises:
        ValueError: the label or rescue scale is not 1/k of the frame, the regions' alignment does
            not hold whole pixels of the rescue grid, a view's shape is not divisible by
            1/label_scale, ``TrackingConfig.network`` names no usable weights, or the regions' U-Net
            has no ``network_stride_px`` (a network without ``pad_multiple``).
    """

    def __init__(self, model: TransducerModel, views: Sequence[View], segmenter, options: PoseConfig,
                 tracking: TrackingConfig, rng: np.random.Generator):
        self.model, self.views, self.segmenter = model, tuple(views), segmenter
        self.options, self.tracking = options, tracking
        self.fast_unet = (segmenter.with_precision(tracking.precision) if isinstance(segmenter, UNetRunner)
                          else None)
        # The full frames' network (from-scratch estimates) and the regions' (warm updates), which
        # TrackingConfig.network may replace by one trained for tracking.
        self._full_unet = self.fast_unet
        if tracking.network is not None:
            self.fast_unet = _tracking_network(tracking.network, segmenter).with_precision(tracking.precision)
        if self.fast_unet is not None:
            net_scale = self.fast_unet.scale
            s = net_scale if tracking.label_scale is None else float(tracking.label_scale)
            align = self.fast_unet.network_stride_px
            if align is None:
                raise ValueError(f"the warm regions' U-Net (a {type(self.fast_unet.network).__name__}) has no "
                                 f"pad_multiple, so no network_stride_px to align the regions to; expected a "
                                 f"histostudy.learning UNet, or a tracker with fast=False")
        else:
            s = 1.0 if tracking.label_scale is None else float(tracking.label_scale)
            align = int(round(1.0 / s))
        self._check_grid("label_scale", s)
        self.label_scale, self._align_px = s, align
        r = tracking.rescue_scale
        self.rescue_scale = float(r) if r is not None and r > s + 1e-12 else None
        if self.rescue_scale is not None:
            self._check_grid("rescue_scale", self.rescue_scale)
            # the regions' boxes (aligned for the label scale) must hold whole pixels of the rescue's grid
            if align % int(round(1.0 / self.rescue_scale)):
                raise ValueError(f"rescue_scale {r!r}: the regions' corners lie on multiples of {align} frame "
                                 f"pixels, not of 1/rescue_scale; expected 1/rescue_scale to divide {align}")
        for i, v in enumerate(self.views):
            k = int(round(1.0 / s))
            if v.shape[0] % k or v.shape[1] % k:
                raise ValueError(f"views[{i}] shape {v.shape} is not divisible by 1/label_scale = {k}")
        self._maps = RegionMaps(occlusion_aware=options.distance_maps == "occlusion_aware")
        self._options_at: dict[float, PoseConfig] = {}
        self._roi_points = np.vstack([p[::ROI_POINT_STRIDE] for p in model.points.values() if len(p)])
        self._refine_points = {k: _subset(np.asarray(p, dtype=np.float64), tracking.refine_points_per_class, rng)
                               for k, p in model.points.items() if len(p)}
        stacked = np.vstack([p for p in model.points.values() if len(p)])
        self._unexplained_points = _subset(stacked, tracking.unexplained_points, rng)
        # The coarse stage's subset (``init_points_per_class`` of each class) is drawn with this
        # seed at every update: the same points each time, and nothing drawn while a pair is
        # refined on one thread as the next is prepared on another.
        self._subset_seed = int(rng.integers(2 ** 63))
        self._pool = ThreadPoolExecutor(max_workers=len(self.views))
        self.last_regions: list[RegionOfInterest] = []

    def _check_grid(self, name: str, s: float) -> None:
        """ValueError unless labels at scale ``s`` come from a U-Net's grid by pooling or by upsampling
        its logits by an integer factor."""
        if self.fast_unet is None:
            return
        net_scale = self.fast_unet.scale
        ratio = max(s, net_scale) / min(s, net_scale)
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"{name} {s!r} must be the U-Net's input scale {net_scale} times or divided by an "
                             f"integer (labels are pooled or the logits upsampled)")

    def _scaled_options(self, scale: float) -> PoseConfig:
        """:attr:`options` with their pixel thresholds at label scale ``scale`` (made once per scale)."""
        if scale not in self._options_at:
            self._options_at[scale] = scaled_pose_options(self.options, scale)
        return self._options_at[scale]

    @property
    def full_frame_segmenter(self):
        """The segmenter of the tracker's from-scratch estimates on full frames: the U-Net through
        :meth:`~histostudy.learning.UNetRunner.segment`, or the segmenter as given."""
        return self.segmenter if self._full_unet is None else self._full_unet

    def _caps(self, scale: float) -> dict:
        """The caps (pixels of a region at label scale ``scale``) at which :meth:`finish` reads the
        distance maps: ``refine`` (the fine stage; None: uncapped), ``search`` (the coarse stage),
        ``verdict`` (the RMS check; None: uncapped), ``consistency`` (the views' agreement), and
        ``reach``, the largest of them, up to which the maps must be exact (None where one reads
        uncapped: the maps are then exact everywhere)."""
        opts = self.options
        caps = {"refine": None if opts.refine_truncation_px is None else opts.refine_truncation_px * scale,
                "search": opts.search_truncation_px * scale,
                "verdict": None if opts.verdict_truncation_px is None else opts.verdict_truncation_px * scale,
                "consistency": (1.0 if opts.refine_truncation_px is None else opts.refine_truncation_px) * scale}
        readers = list(caps.values())
        capped = [c for c in readers if c is not None]
        caps["reach"] = max(capped) if len(capped) == len(readers) else None
        return caps

    # --- stages ---------------------------------------------------------------------------------

    def _labels(self, frame: Frame, region: RegionOfInterest, rng) -> np.ndarray:
        """The region's labels at its scale (largest component kept if the options say so)."""
        r0, r1, c0, c1 = region.box
        if self.fast_unet is not None:
            # above the network's scale its logits are upsampled (UNetRunner.segment_region's upsample)
            net_scale = self.fast_unet.scale
            upsample = int(round(region.scale / net_scale)) if region.scale > net_scale else 1
            labels = self.fast_unet.segment_region(frame, region.box, upsample)
            ratio = region.scale / (net_scale * upsample)
        else:
            full = check_label_image(self.segmenter.segment(frame, rng), frame.shape,
                                     f"the segmentation of view {frame.view.name!r}")
            labels, ratio = full[r0:r1, c0:c1], region.scale
        if ratio != 1.0:
            labels = pool_labels(labels, ratio)
        labels = np.ascontiguousarray(labels, dtype=np.uint8)
        return keep_largest_component(labels) if self.options.largest_component else labels

    def estimate(self, frames: Sequence[Frame], T_prev: np.ndarray, rng: np.random.Generator) -> PoseResult:
        """The pose in ``frames`` refined from ``T_prev`` on the regions of ``T_prev`` (module
        docstring): :meth:`finish` of :meth:`prepare`.

        Raises :class:`~histostudy.pose.result.PoseEstimationError` when a region shows no transducer feature.
        ``result.labels`` are the regions' labels (:attr:`last_regions` says where they lie)."""
        return self.finish(self.prepare(frames, T_prev, rng), T_prev)

    def prepare(self, frames: Sequence[Frame], T_roi: np.ndarray, rng: np.random.Generator | None,
                slot: int = 0, parallel_views: bool | None = None) -> PreparedRegions:
        """Steps 1-3 (docs/tracking.md) of ``frames``: the regions where ``T_roi`` projects, their
        labels and distance maps. ``rng``: for a segmenter that draws (not a U-Net). ``slot`` (0 or
        1) picks the map buffers: :meth:`Tracker.track` prepares the next pair in the other slot
        while this one is refined. ``parallel_views``: the views on two threads (True) or one after
        the other (False); None: ``TrackingConfig.parallel_views``. Safe to run on another thread
        than :meth:`finish`."""
        if parallel_views not in (None, True, False):
            raise ValueError(f"parallel_views must be None, True or False, got {parallel_views!r}")
        plan = self.plan(frames, T_roi, rng, slot)
        in_parallel = self.tracking.parallel_views if parallel_views is None else parallel_views
        return self._segment_and_map(plan, in_parallel)

    def plan(self, frames: Sequence[Frame], T_roi: np.ndarray, rng, slot: int = 0) -> RegionPlan:
        """Step 1 (docs/tracking.md) of ``frames``: the regions where ``T_roi`` projects, and what
        :meth:`prepare_view` needs to segment and map each of them into the map buffers of
        ``slot`` (0 or 1). ``rng``: for a segmenter that draws, a Generator the views share (then
        run them one after the other) or a sequence of one per view; None for a U-Net.
        :meth:`assemble` of the views' outputs is :meth:`prepare`'s result, so that the views can
        run on different threads, in any order."""
        t_start = time.perf_counter()
        if slot not in (0, 1):
            raise ValueError(f"slot must be 0 or 1, got {slot!r}")
        s = self.label_scale
        regions = [region_of_interest(v, self._roi_points, T_roi, margin_px=self.tracking.roi_margin_px,
                                      align_px=self._align_px, scale=s) for v in self.views]
        rngs = list(rng) if isinstance(rng, (list, tuple)) else [rng] * len(frames)
        if len(rngs) != len(frames):
            raise ValueError(f"rng must be a Generator, None or one Generator per view ({len(frames)}), "
                             f"got {len(rngs)}")
        return RegionPlan(list(frames), regions, rngs, [2 * a + slot for a in range(len(frames))], t_start)

    def prepare_rescue(self, prepared: PreparedRegions, rng: np.random.Generator | None) -> PreparedRegions:
        """The regions of ``prepared`` (same boxes) segmented again and mapped at :attr:`rescue_scale`,
        for a second attempt after a refused :meth:`finish` (docs/tracking.md). ``rng``: as for
        :meth:`prepare`. Its maps have buffers of their own: a pair prepared for the next update
        in either slot is kept. ValueError when there is no second attempt (``rescue_scale`` None)."""
        t_start = time.perf_counter()
        if self.rescue_scale is None:
            raise ValueError("rescue_scale is None: this estimator makes no second attempt (TrackingConfig."
                             "rescue_scale must be above the label scale)")
        if prepared.frames is None:
            raise ValueError("prepared holds no frames: pass regions made by RegionEstimator.prepare")
        r = self.rescue_scale
        regions = [RegionOfInterest(box=reg.box, scale=r, view=crop_view(v, reg.box, r), frame_shape=reg.frame_shape)
                   for v, reg in zip(self.views, prepared.regions)]
        n = len(self.views)
        plan = RegionPlan(prepared.frames, regions, [rng] * n, [2 * n + a for a in range(n)], t_start)
        return self._segment_and_map(plan, self.tracking.parallel_views)

    def prepare_view(self, plan: RegionPlan, a: int) -> tuple:
        """Steps 2-3 (docs/tracking.md) of view ``a`` of ``plan``: its region's labels and distance
        maps (in the plan's map buffer of the view), with the seconds of each. Views of one plan may
        run on different threads at once."""
        t0 = time.perf_counter()
        labels = self._labels(plan.frames[a], plan.regions[a], plan.rngs[a])
        t1 = time.perf_counter()
        maps = self._maps.build(plan.buffers[a], plan.regions[a].view, labels,
                                self._caps(plan.regions[a].scale)["reach"])
        return labels, maps, t1 - t0, time.perf_counter() - t1

    @staticmethod
    def assemble(plan: RegionPlan, outputs: Sequence[tuple]) -> PreparedRegions:
        """:meth:`prepare`'s result from ``plan`` and each view's :meth:`prepare_view` output, in the
        order of the views; its ``seconds`` run from the plan to now."""
        timings = {"segmentation": sum(o[2] for o in outputs), "distance_maps": sum(o[3] for o in outputs),
                   "orientation": 0.0, "initialisation": 0.0}
        return PreparedRegions(regions=plan.regions, labels=[o[0] for o in outputs], maps=[o[1] for o in outputs],
                               timings_s=timings, seconds=time.perf_counter() - plan.t_start, frames=plan.frames)

    def _segment_and_map(self, plan: RegionPlan, parallel_views: bool) -> PreparedRegions:
        """Labels and distance maps of each view's region, on two threads or one after the other."""
        views = range(len(plan.frames))
        if parallel_views and self.fast_unet is not None:
            outputs = list(self._pool.map(lambda a: self.prepare_view(plan, a), views))
        else:
            outputs = [self.prepare_view(plan, a) for a in views]
        return self.assemble(plan, outputs)

    def finish(self, prepared: PreparedRegions, T_prev: np.ndarray, parallel: bool | None = None) -> PoseResult:
        """Steps 4-5 (docs/tracking.md): the refinement from ``T_prev`` on ``prepared``'s maps and
        the verdict, at the regions' scale (pixel thresholds times it); the result's
        ``timings_s["total"]`` adds :meth:`prepare`'s seconds. Draws nothing: the point subsets were
        drawn when the estimator was made. ``parallel``: the cost's kernels on numba's threads or not,
        as :class:`~histostudy.pose.cost.PoseCost`'s (None: by the problem's size); the same bits
        either way."""
        if parallel not in (None, True, False):
            raise ValueError(f"parallel must be None, True or False, got {parallel!r}")
        t_start = time.perf_counter()
        s = prepared.regions[0].scale
        regions, labels, maps = prepared.regions, prepared.labels, prepared.maps
        self.last_regions = list(regions)
        timings = dict(prepared.timings_s)
        for region, m in zip(regions, maps):
            if not m.present:
                raise PoseEstimationError(f"view {region.view.name!r}: no transducer feature was segmented in the "
                                          f"tracking region {region.box}; the transducer left it or the "
                                          f"segmentation failed")

        t0 = time.perf_counter()
        opts = self._scaled_options(s)
        costs = pose_costs(self._refine_points, maps, opts, np.random.default_rng(self._subset_seed), label_scale=s,
                           truncated_search=True, parallel=parallel)
        refined = refine_pose(costs, T_prev, "fast", xtol_mm=self.tracking.stop_step_mm,
                              xtol_rad=np.deg2rad(self.tracking.stop_step_deg))
        timings["refinement"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        judge = PoseJudge(costs, [r.view for r in regions], labels, self.model, opts, label_scale=s,
                          unexplained_points_mm=self._unexplained_points)
        verdict = judge(refined.T)
        timings["verdict"] = time.perf_counter() - t0
        timings["retries"] = 0.0
        timings["total"] = time.perf_counter() - t_start + prepared.seconds
        return result_of_refinement(refined, verdict, self.model.focal_point_mm, mode="fast", timings_s=timings,
                                    labels=labels)
