"""How :class:`~._tracker.Tracker`'s fast path runs: :class:`TrackingConfig`, and
:func:`scaled_pose_options`, the :class:`~histostudy.pose.options.PoseConfig` of labels at a scale of
the detector. Units are in the names (``_px`` full-frame pixels, ``_mm`` mm, ``_deg`` degrees).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields

import numpy as np

from histostudy.core import is_real
from histostudy.learning import PRECISIONS, UNetRunner

from ..options import PoseConfig

__all__ = ["TrackingConfig", "scaled_pose_options"]

#: The :class:`PoseConfig` fields that are lengths in detector pixels, multiplied by the label scale
#: by :func:`scaled_pose_options`.
PIXEL_OPTIONS = ("outside_distance_px", "search_truncation_px", "coarse_truncation_px", "max_rms_px",
                 "refine_truncation_px", "verdict_truncation_px", "max_body_rms_px")


def scaled_pose_options(options: PoseConfig, scale: float) -> PoseConfig:
    """``options`` for labels at a scale of the detector: every pixel threshold multiplied by ``scale``.

    The thresholds are :data:`PIXEL_OPTIONS` (those not None), so that each keeps its length on the
    detector (docs/tracking.md, "From scratch in under a second").

    Args:
        options: the :class:`~histostudy.pose.options.PoseConfig` at the detector's pixels.
        scale: label pixels per frame pixel, in (0, 1].

    Returns:
        The scaled :class:`~histostudy.pose.options.PoseConfig`.

    Raises:
        TypeError: ``options`` is not a ``PoseConfig``.
        ValueError: ``scale`` is not a number in (0, 1].
    """
    if not isinstance(options, PoseConfig):
        raise TypeError(f"options must be a histostudy.pose.PoseConfig, got {type(options).__name__}")
    s = float(scale) if not isinstance(scale, bool) else float("nan")
    if not (np.isfinite(s) and 0 < s <= 1):
        raise ValueError(f"scale must be a number in (0, 1] (label pixels per frame pixel), got {scale!r}")
    return dataclasses.replace(options, **{name: getattr(options, name) * s for name in PIXEL_OPTIONS
                                           if getattr(options, name) is not None})


@dataclass(frozen=True)
class TrackingConfig:
    """The fast warm path of :class:`~._tracker.Tracker` (``fast=True`` or ``fast=TrackingConfig(...)``).

    A warm update segments only the region where the last accepted pose projects
    (:func:`~._roi.region_of_interest`), at the segmenter's own resolution, builds the
    region's distance maps into reused buffers (:class:`~._maps.RegionMaps`), refines the
    last pose by Levenberg-Marquardt, coarse to fine, and judges it with the verdict of
    :func:`~histostudy.pose.estimate.estimate_pose` on the region (:mod:`._warm`). From-scratch estimates
    (the first update, re-acquisitions) run :func:`~histostudy.pose.estimate.estimate_pose` on the whole frames at
    ``scratch_label_scale`` (:mod:`._scratch`).

    Args:
        roi_margin_px: frame pixels added on each side of the box of the model projected at the last
            pose. It must cover the motion between two frames (0.5 mm at the isocentre is about
            2.5 px in the default views) plus the reach of the coarse refinement stage's 30 px cap,
            and keep the U-Net's crop edges away from the transducer.
        label_scale: label pixels per frame pixel of the region's segmentation and distance maps
            (1, 1/2, 1/4, ...). None: a U-Net's own input scale (0.5 for the shipped one: its
            arg-max taken at the network's resolution), 1 for other segmenters (their labels
            cropped). A scale below the U-Net's pools its labels by the overlap priority
            (:func:`~histostudy.learning.preprocess.pool_labels`); a scale k times the U-Net's
            upsamples its logits bilinearly before the arg-max (the tracking U-Net at 0.25
            labelling at 0.5: docs/tracking.md, "A network trained for tracking"). Every pixel threshold of
            :class:`~histostudy.pose.options.PoseConfig` is multiplied by it, so that it keeps its length on the
            detector.
        refine_points_per_class: model points per class of the fine refinement stage (drawn once,
            seeded, when the tracker is made); None: every point, as :func:`estimate_pose`.
        stop_step_mm, stop_step_deg: the refinement stops when an accepted step moves the focal point
            less than ``stop_step_mm`` and turns the transducer less than ``stop_step_deg`` (the
            noise of the estimate is tenths of a millimetre: a step a hundred times smaller changes
            nothing a user sees), or as :func:`~histostudy.pose.refine.refine_levenberg_marquardt` stops otherwise.
        unexplained_points: model points (all classes, drawn once, seeded) projected by the
            verdict's unexplained-segmentation check; None: every point.
        parallel_views: in :meth:`~._tracker.Tracker.update`, segment the views and build their maps
            on two threads at once (torch and OpenCV release the GIL; more pairs per second on two
            free cores, nothing gained when other processes hold the cores: docs/tracking.md);
            False: one after the other. :meth:`~._tracker.Tracker.track` schedules the views itself
            (its worker prepares the next pair while this one is refined; the calling thread then
            segments the view the worker has not started).
        precision: what a U-Net computes in (:class:`~histostudy.learning.UNetRunner`): ``"auto"``
            (bfloat16 on a CPU with native bfloat16, else float32:
            :func:`~histostudy.learning.native_bfloat16`), ``"float32"``, ``"bfloat16"`` or
            ``"int8"`` (the checkpoint's stored calibration; faster than float32 on AVX2, single
            poses up to 0.2 mm from float32's: docs/tracking.md).
        network: the U-Net of the warm updates' regions, in place of the tracker's U-Net: None (the
            tracker's segmenter), the name of shipped weights in ``data/models`` (``"unet_tracking"``:
            :func:`~histostudy.learning.tracking_segmenter`, the U-Net trained at input scale 0.25;
            loaded with its SHA-256 checked) or a :class:`~histostudy.learning.UNetRunner`. The
            regions' labels are then at its input scale (``label_scale`` None). From-scratch estimates
            (the first update, re-acquisitions) keep the tracker's segmenter on the whole frames. It
            replaces a U-Net only: with another segmenter (an oracle) the tracker refuses it.
        rescue_scale: the label scale of a second warm attempt after a refused first one (1, 1/2,
            ...; 1: the detector's pixels, the grid of :func:`~histostudy.pose.estimate.estimate_pose`'s verdict),
            before the track is given up and the frames are estimated from scratch. The same regions
            are segmented again at this scale (a U-Net's logits upsampled bilinearly, or another
            segmenter's labels cut at it), and the refinement restarts from the refused pose. It
            runs only where it is above the label scale. On the physical transducer the verdict's
            view agreement measured on the 0.5 grid exceeds the full frame's by 0.4 mm on average
            and refused half the warm starts, the true pose's two times in three; at scale 1 the
            same starts held 20 times in 23 (docs/tracking.md, "Warm starts that hold"). None: no
            second attempt.
        resume_refused: after an update whose pose the verdict refused only for its views' agreement
            (its fit checks passed: the verdict's ``view_disagreement_mm`` measured), the
            next update first tries a warm start from that pose, and estimates from scratch only if
            that is refused too. Such poses lay within about 1 mm of the truth on the physical
            transducer, where a refused estimate from scratch costs many warm updates; False: from
            scratch at once.
        scratch_label_scale: label pixels per frame pixel of the from-scratch estimates (the first
            update, re-acquisitions after a lost track): :func:`~histostudy.pose.estimate.estimate_pose` on the
            whole frames at this scale, every pixel threshold scaled, the searches on
            ``init_points_per_class`` times the scale points per class and the rest on a model of
            ``refine_points_per_class`` points per class (:class:`~._scratch.ScratchEstimator`);
            a pose its verdict refuses is refined and judged again on the full frames, then estimated
            from scratch there. None (default): a U-Net's input scale (0.5 for the shipped one: its
            arg-max at the network's resolution; 0.4 of the seconds of the full frames, with the same
            acceptance and focal errors: docs/tracking.md, "From scratch in under a second"), 1
            for other segmenters. 1: ``estimate_pose`` on the full frames, as before. Below 1, 1/k of
            a U-Net's input scale (its labels pooled by priority).
        scratch_full_frames: a from-scratch estimate its verdict refuses at the label scale is
            refined and judged again on the full frames, then estimated from scratch there (steps
            2-3 of :meth:`~._scratch.ScratchEstimator.estimate`; True, default). False: the refused
            pose is the result, and a from-scratch estimate costs one step at the label scale (a
            live stream, whose next pair is a fraction of a second away, then starts warm from it
            where ``resume_refused`` allows: :class:`histostudy.lab.FrameReceiver`'s default).

    Raises:
        ValueError: a field out of its range or of the wrong kind (the message names the field and
            what was expected), or ``network`` names no usable U-Net weights.
    """

    roi_margin_px: float = 48.0
    label_scale: float | None = None
    refine_points_per_class: int | None = 12000
    stop_step_mm: float = 0.01
    stop_step_deg: float = 0.001
    unexplained_points: int | None = 40000
    parallel_views: bool = True
    precision: str = "auto"
    network: object = None
    rescue_scale: float | None = 1.0
    resume_refused: bool = True
    scratch_label_scale: float | None = None
    scratch_full_frames: bool = True

    def __post_init__(self):
        if not (is_real(self.roi_margin_px) and np.isfinite(self.roi_margin_px) and self.roi_margin_px >= 0):
            raise ValueError(f"roi_margin_px must be a finite number >= 0 (frame pixels), got {self.roi_margin_px!r}")
        for name in ("label_scale", "rescue_scale", "scratch_label_scale"):
            s = getattr(self, name)
            if s is None:
                continue
            k = int(round(1.0 / s)) if is_real(s) and np.isfinite(s) and s > 0 else 0
            if k < 1 or abs(k * s - 1.0) > 1e-9:
                raise ValueError(f"{name} must be None or 1/k for an integer k >= 1 (1, 0.5, 0.25, ...), "
                                 f"got {s!r}")
        for name in ("refine_points_per_class", "unexplained_points"):
            n = getattr(self, name)
            if n is not None and not (is_real(n) and n == int(n) and n >= 1):
                raise ValueError(f"{name} must be None or a positive integer, got {n!r}")
        for name in ("stop_step_mm", "stop_step_deg"):
            value = getattr(self, name)
            if not (is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        for name in ("parallel_views", "resume_refused", "scratch_full_frames"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {self.precision!r}")
        if not (self.network is None or isinstance(self.network, UNetRunner)
                or (isinstance(self.network, str) and self.network.isidentifier())):
            raise ValueError(f"network must be None, the name of shipped U-Net weights in data/models (e.g. "
                             f"'unet_tracking') or a histostudy.learning.UNetRunner, got {self.network!r}")

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """The names of the options, in declaration order."""
        return tuple(f.name for f in fields(cls))

# the 0.1.0 name, deprecated (CHANGELOG.md)
