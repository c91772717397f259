"""Transducer pose estimation from fluoroscopy (§II-B.3, §II-B.4): :func:`estimate_pose`, the frames
segmented, then the stages of :func:`~.from_labels.estimate_pose_from_labels`. Poses are 4x4
``T_carm_transducer`` (mm, C-arm frame); the stages are in docs/pose-estimation.md.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import numpy as np

from histostudy.core import check_items, stage
from histostudy.imaging import Frame
from histostudy.learning import OrientationSource, Segmenter
from histostudy.transducer import TransducerModel

from .directions import SourceDirections
from .estimate_memo import memoised_estimates
from .from_labels import estimate_pose_from_labels
from .labels import segment_frames
from .learned_stages import default_stages
from .options import PoseConfig, pose_generator
from .result import PoseResult, refused

__all__ = ["estimate_pose"]


@stage("pose")
@memoised_estimates
def estimate_pose(frames: Sequence[Frame], model: TransducerModel, *, segmenter: Segmenter | None = None,
                  orientation: OrientationSource | None = None, rng: int | np.random.Generator | None = None,
                  initial_pose=None, options: PoseConfig | None = None, **option_overrides) -> PoseResult:
    """Estimate ``T_carm_transducer`` from one or more frames (§II-B.3-4).

    Inside a :func:`~.estimate_memo.shared_estimates` scope a call equal to an earlier one (same
    frames, stages, options and Generator state) returns that call's result again, exactly.

    Args:
        frames: the fluoroscopic frames, each with its view (>= 1; the paper: planes A and B).
        model: the digital model whose points enter eq. 3 (the paper: the 0.47 mm model).
        segmenter: frame -> label image; default: the shipped U-Net when its weights are present
            and pass their check, else :class:`OracleSegmenter` (the frames' reference labels, a
            synthetic-study stand-in that cannot segment a real frame) — see :func:`default_stages`.
        orientation: frame -> (azimuth, elevation); default: the shipped stage of
            :func:`histostudy.pose.conic_orientation.default_orientation` (the inner-boundary conic
            initialiser, the VGG19 regressor where a view shows no ellipse), else
            :class:`OracleOrientation` (the true angles with the paper's errors). A source with a
            ``direction_candidates_from_labels(frame, labels, rng, maps=)`` method (the geometric
            :class:`~histostudy.pose.conic_orientation.ConicOrientation`) is given the segmentation
            made here and returns each view's two candidate directions itself.
        rng: an int seed or a Generator for the segmenter's and orientation's draws, the point
            subsets and the silhouette seed; None: ``numpy.random.default_rng(0)``, a fixed seed
            (:data:`~.options.DEFAULT_SEED`, :func:`~.options.pose_generator`), so that the same
            frames give the same pose.
        initial_pose: a 4x4 pose to start the refinement from (tracking warm start); skips the
            initialisation.
        options: how to run: mode, initialisation, distance maps, truncations, verdict
            thresholds (:class:`~.options.PoseConfig`; default ``PoseConfig()``).
        **option_overrides: any field of :class:`~.options.PoseConfig` as a keyword
            (``mode="fast"``, ``refine_truncation_px=None``, ...); each overrides that field of
            ``options``. An unknown keyword raises TypeError.

    Returns:
        :class:`~.result.PoseResult`: ``T_carm_transducer`` (4x4, mm), the focal point (eq. 5), the
        cost, the seconds per stage and the verdict.

    Raises:
        TypeError: ``frames`` holds something other than frames, ``model`` is not a
            ``TransducerModel``, ``options`` is not a ``PoseConfig`` or an override is unknown.
        ValueError: ``frames`` is empty, or an option override is out of its range.
        PoseEstimationError: a view shows no transducer feature, or the verdict refuses the pose
            and ``options.raise_on_failure`` is set.
    """
    t_start = time.perf_counter()
    frames = check_items(frames, "frames", Frame, type_name="histostudy.imaging.frame.Frame")
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a TransducerModel, got {type(model).__name__}")
    options = _resolve_options(options, option_overrides)
    rng = pose_generator(rng)
    segmenter = default_stages()[0] if segmenter is None else segmenter
    orientation = default_stages()[1] if orientation is None else orientation
    t0 = time.perf_counter()
    labels = segment_frames(frames, segmenter, rng)
    seconds = time.perf_counter() - t0
    # Judged here, once the segmentation's seconds are counted in the result.
    result = estimate_pose_from_labels(labels, [f.view for f in frames], model,
                                       orientation=SourceDirections(orientation, frames), rng=rng,
                                       options=dataclasses.replace(options, raise_on_failure=False),
                                       initial_pose=initial_pose)
    result.timings_s["segmentation"] += seconds
    result.timings_s["total"] = time.perf_counter() - t_start
    if not result.verdict.ok and options.raise_on_failure:
        raise refused(result)
    return result


def _resolve_options(options, overrides: dict) -> PoseConfig:
    """``options`` (default ``PoseConfig()``) with the keyword ``overrides`` of its fields applied."""
    return PoseConfig.resolve(options, overrides, caller="estimate_pose",
                               keywords="segmenter, orientation, rng, initial_pose, options")
