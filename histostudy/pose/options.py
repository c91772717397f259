"""The options of :func:`~.estimate.estimate_pose` (§II-B.3-4), one frozen, validated record
(:class:`PoseConfig`), and the seeding rule of every pose entry point (:func:`pose_generator`).
Units are in the names: ``_px`` detector pixels, ``_mm`` mm in the C-arm frame, ``_deg`` degrees.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from types import MappingProxyType

import numpy as np

from histostudy.core import as_generator, is_real

from .cost import OUTSIDE_DISTANCE_PX
from .distance_maps import feature_class

__all__ = ["DEFAULT_SEED", "INIT_METHODS", "MAP_KINDS", "MODES", "PoseConfig", "pose_generator"]

#: The seed of the Generator that :func:`~.estimate.estimate_pose`, :func:`~.from_labels.estimate_pose_from_labels`
#: and :class:`~histostudy.pose.tracking.Tracker` draw from when given ``rng=None``.
DEFAULT_SEED = 0


def pose_generator(rng) -> np.random.Generator:
    """The Generator of a pose entry point's ``rng``: a Generator as given, an int seed's
    ``numpy.random.default_rng(seed)``, None ``numpy.random.default_rng(DEFAULT_SEED)`` (so that
    the same inputs give the same pose; docs/architecture.md, "Seeding and determinism").
    Anything else raises TypeError naming ``rng``."""
    return np.random.default_rng(DEFAULT_SEED) if rng is None else as_generator(rng)

MODES = ("paper", "fast")
INIT_METHODS = ("robust", "paper")
MAP_KINDS = ("occlusion_aware", "per_class")


@dataclass(frozen=True)
class PoseConfig:
    """How :func:`~.estimate.estimate_pose` runs: its search, refinement and verdict settings.

    ``estimate_pose(frames, model, options=PoseConfig(mode="fast"))``; a keyword argument of
    :func:`~.estimate.estimate_pose` named as a field overrides that field of ``options``. Every
    field is checked when the record is made: a bad value raises a ValueError naming the field,
    the value and what was expected.

    Args:
        mode: ``"paper"`` (Nelder-Mead, 1000 iterations, tolerances 0.01) or ``"fast"``
            (Levenberg-Marquardt with analytic Jacobian, coarse-to-fine).
        init: ``"paper"`` runs §II-B.4 as written: the translation grids at one axial angle, scored
            by eq. 3 with the paper's 0.1 px constant, then the axial search. ``"robust"`` (default)
            scores the grid and axial searches with distances truncated at
            ``search_truncation_px`` (points off the detector count as truncated too), seeds the
            coarse grids at four axial angles (scored with distances truncated at
            ``coarse_truncation_px``, about a coarse grid step, for a basin as wide as the grid,
            off-detector points at that and at half of it, three chains of each carried on),
            adds a 1 cm medium grid before the fine one, repeats the fine grids after the axial search and
            carries the three best axial minima through a short Levenberg-Marquardt polish. With two
            or more views, a silhouette seed (:func:`~.silhouette.silhouette_candidates`: the visible
            part's occupancy centroids matched by Gauss-Newton, the axial angle chosen by the
            silhouettes' overlap) proposes two more chains, and the best of them is carried
            through the axial search beside the best coarse chain: where most of the transducer is
            off the detectors, the coarse grid's scores are nearly flat (notebook 04's robustness
            sweep: 93 % -> 98-99 % success at 0.25 mm renders). With
            the paper's constant a pose with the whole model off the detector costs 0.01 px² per
            class, less than any real alignment: the grid search then returns it (measured in
            notebook 04's robustness sweep).
        distance_maps: ``"per_class"`` builds eq. 3's maps as written (distance to the nearest
            pixel of the same class); ``"occlusion_aware"`` (default, beyond the paper) lets a
            pixel of a higher-priority class count for the classes it hides (see
            :class:`~.distance_maps.DistanceMaps`): with priority-resolved labels, per-class maps bias the
            optimum by up to about 1 mm on noise-free frames, occlusion-aware maps by a few
            hundredths (tests/pose/test_pose_estimate.py; notebook 04 compares both).
        class_weights: eq. 3's ``lambda_k`` (default 1 each).
        outside_distance_px: eq. 3's constant distance for points off the map (paper 0.1 px).
        init_points_per_class: points per class of the cheaper cost the grid and axial searches use.
        search_centre_mm: centre of the first translation grid (paper: the isocentre).
        max_rms_px, min_inside_fraction: verdict thresholds (see :class:`PoseVerdict`). The RMS
            threshold allows for a learned segmentation's label noise: with the shipped U-Net,
            correct poses (< 2 mm) reach 4-6 px (30 random poses, seed 4242); it no longer tells
            a wrong pose alone, ``max_view_disagreement_mm`` does (docs/learned-stages.md).
        max_body_rms_px: beyond the paper; the largest RMS distance (px, per view) of the
            element body's model points (:attr:`Feature.TRANSDUCER`, the class a segmentation
            finds best: the shipped U-Net's IoU 0.94). At a right pose they lie on it even when
            the thin classes are half missed; a pose turned or shifted by millimetres moves them
            off. With the shipped U-Net, estimates within 2 mm of 100 random poses (seed 5151)
            had a median of 0.07 px and a 95th percentile of 0.19 px; five of the seven off by
            more had 1.0-5.4 px. Judged with the occlusion-aware maps only: with per-class maps a
            body point under a thin feature is off its class by the feature's width. None skips
            the check.
        largest_component: beyond the paper; keep only the largest connected component of each
            view's segmented foreground (:func:`~histostudy.learning.segment.keep_largest_component`): the
            transducer projects as one body, so other components are a segmentation's false
            positives, which would otherwise pull the search and fail the unexplained-segmentation
            check. ``PoseResult.labels`` are the labels after this step.
        max_unexplained_fraction: beyond the paper; the largest fraction of a view's segmented
            pixels that may lie farther than ``verdict_truncation_px`` from every projected model
            point (:attr:`PoseVerdict.unexplained_fraction`). Eq. 3 and the RMS look from the model
            to the labels only: a pose that pushes most of the model off the detectors fits what
            stays on it, with the rest of the segmented transducer left unexplained (measured: a
            pose 117 mm off, RMS 4.7 px, 41 % of view A's segmentation unexplained; poses within
            2 mm, at most 2 %). None skips the check.
        max_view_disagreement_mm: beyond the paper; with two or more views, the cross-view check of
            a pose that passed the others. From the pose, each view's cost alone (distances capped
            at ``refine_truncation_px``, 1 px if None) is minimised by Levenberg-Marquardt; the
            focal point's move across that view's ray through it (the depth, which one view does
            not fix, left out) is the view's disagreement. Where both views' features fit the
            pose, neither pulls it away; a pose that trades one view's misread features against
            the other's sits between two single-view optima and fails. Chosen on 30 random poses
            (seed 4242, shipped U-Net): estimates within 2 mm moved at most 1.25 mm, four of the
            five wrong ones 1.9-3.1 mm; validated on fresh seeds in docs/learned-stages.md. None
            skips the move's check.
        min_view_gain_px2: beyond the paper; with ``max_view_disagreement_mm``, a view's move beyond
            that bound fails the pose only where the view's own optimum also lowers its eq. 3 cost
            (capped as above) by at least this many px² (:attr:`PoseVerdict.view_gain_px2`): a long
            move bought with almost no gain is a flat valley of one view's cost, not a conflict
            (docs/campaigns.md, "What a view's move buys"). None: the move alone decides.
        max_view_gain_px2: beyond the paper; with two or more views, a pose fails where a view's own
            optimum lowers its eq. 3 cost by more than this many px², however short the move. None
            skips the check. Both gain bounds are per network (its labels set the cost's scale):
            calibrate them on held-out frames before use.
        raise_on_failure: raise :class:`PoseEstimationError` on a failed verdict (else return it).
        retry_hypotheses: when the refinement from the best initial hypothesis fails the verdict,
            refine the initialisation's other hypotheses too (``init="robust"`` keeps three) and
            keep the plausible one of lowest cost; in the fast mode, if none is plausible, the
            best hypothesis is refined by Nelder-Mead as a last resort. ``timings_s["retries"]``
            then holds their time.
        refine_truncation_px: beyond the paper. The refinement (both modes) minimises eq. 3 with
            each distance capped at this many pixels; None minimises eq. 3 as written. A U-Net
            misses whole stretches of a thin class (a gap line, a part of the rim): eq. 3's
            squared distances let the model points there, tens of pixels from any pixel of their
            class, pull the pose by millimetres. Capped, they cost a constant and pull nothing,
            while every point within the cap counts as in eq. 3; the refinement starts from the
            initialisation's pose, already fitted with 30 px caps, so a narrow cap costs no basin.
            Measured on 18 poses of notebook 04's setting (0.25 mm renders, oracle orientation,
            fast mode), mean focal error uncapped / 3 px / 1 px: shipped U-Net 2.3 / 0.67 / 0.45 mm
            (uncapped, one pose 14 mm off and judged implausible), labels with Table I's errors
            0.46 / 0.41 / 0.38 mm; exact labels 0.20 mm at 3 px and at 1 px.
        verdict_truncation_px: the verdict's RMS distance counts each point at most this far
            (None: uncapped), so that stretches of a class the segmentation missed do not fail a
            pose that fits the rest; a wrong pose still has most points beyond it.
        direction_spread_limit_deg: with ``init="robust"`` and two or more views, when the views'
            orientation estimates disagree by more than this (the mean pairwise angle of
            :func:`~histostudy.learning.orientation.select_direction`), one view's estimate is off and
            their mean is off too: the initialisation then also starts from each view's own two
            direction candidates and keeps the lowest-cost start. Estimates with the paper's
            regression errors (1-2 deg) stay well below 15 deg, and their estimates are unchanged;
            a VGG19 that misreads one view by 90 deg no longer sends the pose astray. When the
            views agree but the pose fails the verdict (both misread alike) and ``retry_hypotheses``
            is set, the per-view starts are tried then. ``init.stages["direction_starts"]``
            records how many directions were started from.

    Raises:
        ValueError: a field out of its range or of the wrong kind (the message names the field,
            the value and what was expected).
    """

    mode: str = "paper"
    init: str = "robust"
    distance_maps: str = "occlusion_aware"
    class_weights: Mapping | None = None
    outside_distance_px: float = OUTSIDE_DISTANCE_PX
    search_truncation_px: float = 30.0
    coarse_truncation_px: float = 150.0
    init_points_per_class: int = 1500
    search_centre_mm: tuple = (0.0, 0.0, 0.0)
    max_rms_px: float = 6.0
    min_inside_fraction: float = 0.02
    raise_on_failure: bool = True
    retry_hypotheses: bool = True
    direction_spread_limit_deg: float = 15.0
    refine_truncation_px: float | None = 1.0
    verdict_truncation_px: float | None = 10.0
    max_view_disagreement_mm: float | None = 1.5
    min_view_gain_px2: float | None = None
    max_view_gain_px2: float | None = None
    max_body_rms_px: float | None = 1.0
    max_unexplained_fraction: float | None = 0.1
    largest_component: bool = True

    def __post_init__(self):
        for name, choices in (("mode", MODES), ("init", INIT_METHODS), ("distance_maps", MAP_KINDS)):
            if getattr(self, name) not in choices:
                raise ValueError(f"{name} must be one of {choices}, got {getattr(self, name)!r}")
        if self.class_weights is not None:
            if not isinstance(self.class_weights, Mapping):
                raise ValueError(f"class_weights must be None or a dict {{Feature: lambda_k >= 0}}, "
                                 f"got {self.class_weights!r}")
            for key, value in self.class_weights.items():
                feature = feature_class(key, "class_weights")
                if not (is_real(value) and np.isfinite(value) and value >= 0):
                    raise ValueError(f"class_weights[{feature.name}] must be finite and >= 0, got {value!r}")
            # Read-only, so that a frozen record cannot change under a caller's later edits.
            object.__setattr__(self, "class_weights", MappingProxyType(dict(self.class_weights)))
        if not (is_real(self.outside_distance_px) and np.isfinite(self.outside_distance_px)
                and self.outside_distance_px >= 0):
            raise ValueError(f"outside_distance_px must be a finite number >= 0 (pixels), "
                             f"got {self.outside_distance_px!r}")
        for name in ("search_truncation_px", "coarse_truncation_px"):
            value = getattr(self, name)
            if not (is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0 (pixels), got {value!r}")
        n = self.init_points_per_class
        if not (is_real(n) and np.isfinite(n) and n == int(n) and n >= 1):
            raise ValueError(f"init_points_per_class must be a positive integer, got {n!r}")
        centre = np.asarray(self.search_centre_mm, dtype=object).reshape(-1)
        if centre.shape != (3,) or not all(is_real(c) and np.isfinite(c) for c in centre):
            raise ValueError(f"search_centre_mm must be 3 finite numbers (x, y, z in mm, C-arm frame), "
                             f"got {self.search_centre_mm!r}")
        object.__setattr__(self, "search_centre_mm", tuple(float(c) for c in centre))
        if not (is_real(self.max_rms_px) and self.max_rms_px > 0):
            raise ValueError(f"max_rms_px must be a number > 0 (pixels; inf: no limit), got {self.max_rms_px!r}")
        if not (is_real(self.min_inside_fraction) and 0 <= self.min_inside_fraction <= 1):
            raise ValueError(f"min_inside_fraction must be a number in [0, 1], got {self.min_inside_fraction!r}")
        for name in ("raise_on_failure", "retry_hypotheses", "largest_component"):
            if getattr(self, name) not in (True, False):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        spread = self.direction_spread_limit_deg
        if not (is_real(spread) and 0 < spread <= 180):
            raise ValueError(f"direction_spread_limit_deg must be a number in (0, 180], got {spread!r}")
        for name in ("refine_truncation_px", "verdict_truncation_px", "max_view_disagreement_mm", "max_body_rms_px",
                     "max_unexplained_fraction", "min_view_gain_px2", "max_view_gain_px2"):
            value = getattr(self, name)
            if value is not None and not (is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be None or a finite number > 0, got {value!r}")
        if self.min_view_gain_px2 is not None and self.max_view_disagreement_mm is None:
            raise ValueError(f"min_view_gain_px2={self.min_view_gain_px2!r} qualifies max_view_disagreement_mm's "
                             "check, which is off (None): set max_view_disagreement_mm too, or leave it None")

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """The names of the options, in declaration order (each also a keyword of estimate_pose)."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def resolve(cls, options, overrides: dict, *, caller: str, keywords: str) -> PoseConfig:
        """``options`` (default ``PoseConfig()``) with the keyword ``overrides`` of its fields
        applied, for a ``caller`` whose own keywords are ``keywords``: an unknown keyword raises
        TypeError naming it, the caller's keywords and the fields."""
        if options is None:
            options = cls()
        elif not isinstance(options, cls):
            raise TypeError(f"options must be a histostudy.pose.PoseConfig, got {type(options).__name__}")
        unknown = sorted(set(overrides) - set(cls.field_names()))
        if unknown:
            raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}; its keywords are "
                            f"{keywords} and the fields of PoseConfig: {', '.join(cls.field_names())}")
        return replace(options, **overrides) if overrides else options

# the 0.1.0 name, deprecated (CHANGELOG.md)
