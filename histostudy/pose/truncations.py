"""The costs stage of :func:`~histostudy.pose.estimate_pose_from_labels` (§II-B.3, eq. 3): one
flattened copy of the distance maps and every capped or point-subset view of eq. 3 the later
stages read (:class:`PoseCosts`, :func:`pose_costs`). Distances in label pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .cost import PoseCost
from .distance_maps import DistanceMaps
from .options import PoseConfig

__all__ = ["PoseCosts", "pose_costs"]


@dataclass
class PoseCosts:
    """Eq. 3 at the truncations and point subsets one estimate reads; all share one flattened copy
    of the maps.

    Attributes:
        full: every model point, distances uncapped (eq. 3 as written).
        refine: the refinement's cost: ``full`` capped at ``refine_truncation_px``.
        coarse: ``init_points_per_class`` points of each class, drawn once.
        search: the grid and axial searches' cost: ``coarse`` with distances (and the off-detector
            constant) truncated at ``search_truncation_px`` for the robust initialisation, else
            ``coarse`` itself.
        polish: the coarse stage of the fast refinement and the robust initialisation's polish:
            ``search`` with eq. 3's own off-detector constant (else ``coarse``).
        verdict: ``coarse`` capped at ``verdict_truncation_px``, the verdict's RMS distances.
        consistency_cap_px: the cap of :attr:`consistency`.
    """

    full: PoseCost
    refine: PoseCost
    coarse: PoseCost
    search: PoseCost
    polish: PoseCost
    verdict: PoseCost
    consistency_cap_px: float

    @cached_property
    def consistency(self) -> PoseCost:
        """The views' agreement check's cost (:func:`~.verdict.check_view_agreement`): ``coarse``
        capped at :attr:`consistency_cap_px`; made when first read."""
        return self.coarse.capped(self.consistency_cap_px)


def pose_costs(points: Mapping, maps: Sequence[DistanceMaps], options: PoseConfig, rng: np.random.Generator, *,
               label_scale: float = 1.0, truncated_search: bool | None = None,
               parallel: bool | None = None) -> PoseCosts:
    """The :class:`PoseCosts` of ``points`` (per class, mm, transducer frame) on ``maps``.

    Args:
        points, maps: eq. 3's model points and each view's distance maps.
        options: the pixel thresholds in the maps' pixels (for labels at a scale ``s`` of the
            detector, :func:`~histostudy.pose.tracking._scratch.scaled_pose_options`).
        rng: draws the ``coarse`` point subset (one draw, nothing else).
        label_scale: label pixels per detector pixel; scales only the fixed 1 px cap of the views'
            agreement check used where ``refine_truncation_px`` is None.
        truncated_search: the robust initialisation's truncated ``search`` and ``polish``; None:
            where ``options.init == "robust"``.
        parallel: :class:`PoseCost`'s (None: by the problem's size; the same bits either way).
    """
    if truncated_search is None:
        truncated_search = options.init == "robust"
    outside = options.outside_distance_px
    full = PoseCost(points, maps, class_weights=options.class_weights, outside_distance_px=outside, parallel=parallel)
    refine = full.capped(options.refine_truncation_px)
    coarse = full.subset(options.init_points_per_class, rng)
    verdict = coarse.capped(options.verdict_truncation_px)
    if truncated_search:
        tau = float(options.search_truncation_px)
        search = coarse.capped(tau, outside_distance_px=tau)
        # The local refinements' robust cost: the same truncated distances, but eq. 3's own
        # constant for points off the detector. With the truncation as the off-detector cost, a
        # pose that pulls more of the model onto the detector wins over a better-aligned one
        # (measured: a 1-2 mm pull on frames where much of the transducer is outside the view).
        polish = search.with_outside_distance(outside)
    else:
        search = polish = coarse
    cap = 1.0 * label_scale if options.refine_truncation_px is None else options.refine_truncation_px
    return PoseCosts(full=full, refine=refine, coarse=coarse, search=search, polish=polish, verdict=verdict,
                     consistency_cap_px=cap)
