"""Tracking the transducer through a stream of biplane frames (§II-A, §II-B.3-4): :class:`Tracker`,
which warm-starts each estimate from the last accepted pose and re-acquires from scratch when the
verdict refuses. Poses are 4x4 ``T_carm_transducer`` (mm); design and figures in docs/tracking.md.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Iterator, Sequence

import numpy as np

from histostudy.core import check_items, stage
from histostudy.imaging import Frame, View
from histostudy.transducer import TransducerModel

from ..estimate import estimate_pose
from ..learned_stages import default_stages
from ..options import PoseConfig, pose_generator
from ..result import PoseEstimationError, PoseResult, add_timings, refused
from ._input import frames_for_views
from ._options import TrackingConfig
from ._pipeline import pipelined_updates
from ._scratch import ScratchEstimator, scratch_estimator
from ._warm import RegionEstimator
from ._warm_up import warm_up

__all__ = ["Tracker"]

class Tracker:
    """The transducer's pose, pair after pair (§II-A, §II-B.3-4): warm-started :func:`~histostudy.pose.estimate_pose`.

    ``Tracker(model, views).update(frames)`` returns a :class:`~histostudy.pose.result.PoseResult` per call.

    Args:
        model: the digital model whose points enter eq. 3 (the paper: the 0.47 mm model).
        views: the C-arm views the frames are taken with, in the order ``update`` receives them
            (the paper: planes A and B, §II-D); one view or a non-empty sequence of :class:`View`.
        segmenter, orientation: the learned stages; None: those :func:`~histostudy.pose.estimate.estimate_pose`
            picks (:func:`~histostudy.pose.learned_stages.default_stages`: the shipped U-Net and conic/VGG19
            orientation, else the oracles with a warning), chosen once here.
        rng: a ``numpy.random.Generator`` or an int seed for every random draw of the estimates;
            None: ``numpy.random.default_rng(0)``, the fixed seed of every pose entry point
            (:data:`~histostudy.pose.options.DEFAULT_SEED`,
            :func:`~histostudy.pose.options.pose_generator`): the same frames in the same order
            give the same poses, with or without a seed.
        options: a :class:`~histostudy.pose.options.PoseConfig`, as for
            :func:`~histostudy.pose.estimate.estimate_pose`. Unlike there, ``raise_on_failure``
            defaults to False when no ``options`` are given: a tracker reports a failed verdict in
            the result (``result.verdict.ok``) rather than stopping the stream.
        **option_overrides: keyword overrides of its fields, as for
            :func:`~histostudy.pose.estimate.estimate_pose`.
        fast: True (default) or a :class:`~._options.TrackingConfig`: warm updates run on the
            regions where the last pose projects
            (:class:`~._warm.RegionEstimator`: Levenberg-Marquardt whatever ``mode``, which
            then applies to the from-scratch estimates only); ``result.labels`` are then the regions'
            labels at the label scale, and :attr:`last_regions` says where they lie. From-scratch
            estimates then run at ``TrackingConfig.scratch_label_scale`` (default: a U-Net's input
            scale, 0.5; :class:`~._scratch.ScratchEstimator`): ``estimate_pose`` on the
            U-Net's arg-max at its own resolution, every pixel threshold scaled (several times
            faster than on the full frames: docs/tracking.md); a pose its verdict refuses is
            refined and judged again on the full frames (``result.labels`` are then full-resolution). With scale 1, or
            another segmenter, they segment the full frames (a U-Net through
            :meth:`~histostudy.learning.UNetRunner.segment`: 99.9 % the checkpoint's labels, 100 % in
            float32).
            ``TrackingConfig(network="unet_tracking")`` runs the warm regions through the U-Net
            trained at input scale 0.25 instead (more warm pairs per second, focal errors
            about 0.2 mm above the full-frame path's: docs/tracking.md, "A network trained for
            tracking"); the from-scratch estimates keep the tracker's U-Net. A refused fast warm
            start is tried again at ``TrackingConfig.rescue_scale`` (default 1: the detector's
            pixels) from the refused pose, on the same regions, before the track is lost; an
            accepted second attempt is a warm update (its labels at that scale), counted in
            ``n_rescued``. After a pose the verdict refused only for its views' agreement (the fit
            checks passed), the next update first tries a warm start from it
            (``TrackingConfig.resume_refused``; counted in ``n_resume_attempts`` / ``n_resumed``)
            before estimating from scratch. False: every warm update is
            :func:`~histostudy.pose.estimate.estimate_pose` from the last pose on the full frames,
            and every estimate from scratch ``estimate_pose`` itself (the study's path: what
            notebook 06 and ``study.your_data`` run).

    The counters below are the tracker's record: read them, do not set them.

    Attributes:
        n_updates: calls of :meth:`update` that ran (bad input raises before counting).
        n_warm: updates whose warm start was accepted (at the first attempt or, with ``fast``, the
            second).
        n_rescue_attempts: with ``fast``, refused warm starts tried a second time at
            ``TrackingConfig.rescue_scale``.
        n_rescued: of those, the second attempts the verdict accepted (counted in ``n_warm`` too, not
            in ``n_lost``).
        n_from_scratch: estimates run from scratch (first updates, updates after a failure, and
            re-acquisitions).
        n_lost: warm starts whose verdict failed (both attempts, with ``fast``) or that found no
            feature: the track was lost.
        n_resume_attempts: with ``fast``, updates after a refused pose that first tried a warm start
            from it (``TrackingConfig.resume_refused``).
        n_resumed: of those, the warm starts accepted (counted in ``n_warm`` too). Every update ends
            warm or from scratch: ``n_updates = n_warm + n_from_scratch`` (+ updates that raised).
        n_reacquired: of those, the updates whose from-scratch estimate on the same frames was
            accepted.
        n_accepted, n_failed: updates that ended with an accepted pose / without one (a failed
            verdict, or :class:`~histostudy.pose.result.PoseEstimationError` raised).
        stage_seconds: seconds per stage (the keys of ``PoseResult.timings_s``: segmentation,
            distance_maps, orientation, initialisation, refinement, verdict, retries, total), summed
            over every estimate run, a lost warm start's included.
        update_seconds: wall seconds spent in :meth:`update`, input checks included.
        tracking_options: the :class:`~._options.TrackingConfig` of the fast warm path (None
            without ``fast``).

    Raises:
        TypeError: ``model`` is not a ``TransducerModel``, ``views`` holds something other than
            views, ``fast`` is not True, False or a ``TrackingConfig``, ``options`` is not a
            ``PoseConfig`` or an override is unknown.
        ValueError: ``views`` is empty, or an option override is out of its range.
    """

    #: The counters above, in the order of :meth:`stats`; :meth:`reset` zeroes them.
    COUNTERS = ("n_updates", "n_warm", "n_from_scratch", "n_lost", "n_reacquired", "n_accepted", "n_failed",
                "n_rescue_attempts", "n_rescued", "n_resume_attempts", "n_resumed")
    # set by reset() through COUNTERS
    n_updates: int
    n_warm: int
    n_from_scratch: int
    n_lost: int
    n_reacquired: int
    n_accepted: int
    n_failed: int
    n_rescue_attempts: int
    n_rescued: int
    n_resume_attempts: int
    n_resumed: int

    def __init__(self, model: TransducerModel, views: Sequence[View] | View, *, segmenter=None, orientation=None,
                 rng=None, options: PoseConfig | None = None, fast: bool | TrackingConfig = True,
                 **option_overrides):
        if not isinstance(model, TransducerModel):
            raise TypeError(f"model must be a histostudy.transducer.TransducerModel, got {type(model).__name__}")
        views = check_items(views, "views", View, type_name="histostudy.imaging.View")
        self.model = model
        self.views = tuple(views)
        if options is None:
            option_overrides.setdefault("raise_on_failure", False)
        self.options = PoseConfig.resolve(options, option_overrides, caller="Tracker",
                                           keywords="segmenter, orientation, rng, options, fast")
        # Every estimate runs without raising on a failed verdict: a failed warm start is the
        # tracker's cue to re-acquire, not an error. ``options.raise_on_failure`` applies to the
        # update's final result only.
        self._estimate_options = dataclasses.replace(self.options, raise_on_failure=False)
        if segmenter is None or orientation is None:
            default_segmenter, default_orientation = default_stages()
            segmenter = default_segmenter if segmenter is None else segmenter
            orientation = default_orientation if orientation is None else orientation
        self.segmenter, self.orientation = segmenter, orientation
        self.rng = pose_generator(rng)
        if fast is True:
            fast = TrackingConfig()
        elif fast is not False and not isinstance(fast, TrackingConfig):
            raise TypeError(f"fast must be True, False or a histostudy.pose.TrackingConfig, got {fast!r}")
        self.tracking_options = fast if isinstance(fast, TrackingConfig) else None
        self._region: RegionEstimator | None = None
        # From scratch at the label scale (TrackingConfig.scratch_label_scale); None: full frames.
        self._scratch: ScratchEstimator | None = None
        if self.tracking_options is not None:
            self._region = RegionEstimator(model, self.views, segmenter, self._estimate_options,
                                           self.tracking_options, self.rng)
            self._scratch = scratch_estimator(model, self.views, self._region.full_frame_segmenter, orientation,
                                              self._estimate_options, self.tracking_options, self.rng)
        self.reset()

    # --- state ----------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the track and zero the counters: the next update estimates from scratch."""
        self._last_pose: np.ndarray | None = None
        self.last_result: PoseResult | None = None
        self.last_kind: str | None = None
        for name in self.COUNTERS:
            setattr(self, name, 0)
        self._refused_pose: np.ndarray | None = None  # the last update's refused pose, for a resumed start
        self.stage_seconds: dict[str, float] = {}
        self.update_seconds = 0.0
        if self._region is not None:
            self._region.last_regions = []

    @property
    def last_pose(self) -> np.ndarray | None:
        """The last accepted ``T_carm_transducer`` (4x4, mm; a copy), None before the first
        accepted pose and after the track was lost."""
        return None if self._last_pose is None else self._last_pose.copy()

    @property
    def last_regions(self) -> list | None:
        """With ``fast``: each view's :class:`~._roi.RegionOfInterest` of the last warm
        update that ran (None before one, and without ``fast``)."""
        if self._region is None or not self._region.last_regions:
            return None
        return list(self._region.last_regions)

    @property
    def tracking(self) -> bool:
        """True when the next update will warm-start from :attr:`last_pose`."""
        return self._last_pose is not None

    def stats(self) -> dict:
        """The counters and the summed stage seconds as a plain dict (JSON-ready)."""
        return {**{name: getattr(self, name) for name in self.COUNTERS}, "stage_seconds": dict(self.stage_seconds),
                "update_seconds": self.update_seconds}

    def warm_up(self, frames=None, *, seed: int = 0) -> dict:
        """Run the whole path once before the first real pair, then put the tracker back as it was.

        From scratch, then warm, on ``frames``; the track, the counters and the Generator's state are
        restored, so the poses that follow are the same as without it. Loads or compiles the kernels and
        builds the network's primitives that a live stream's first pair would otherwise wait for.

        Args:
            frames: a pair as :meth:`update` takes it; None: a synthetic pair of :attr:`model` at the
                views' isocentre (:func:`~._warm_up.warm_up_pair`).
            seed: the seed of the synthetic pair's draws.

        Returns:
            ``{"seconds", "kinds", "accepted"}`` of the two warm-up updates.

        Raises:
            ValueError: ``frames`` do not match the tracker's views.
        """
        return warm_up(self, frames, seed=seed)

    # --- the update -----------------------------------------------------------------------------

    def update(self, frames) -> PoseResult:
        """The pose in ``frames``: one per view, in the order of ``views``.

        Args:
            frames: a sequence of :class:`~histostudy.imaging.Frame` (taken with the tracker's
                views) or of 2-D arrays of line integrals ``(rows, cols)`` = each view's shape
                (wrapped as ``Frame(image, view)``); a ``(n_views, rows, cols)`` array is read as
                its n_views images.

        Returns:
            The :class:`~histostudy.pose.result.PoseResult`; ``result.init`` is None for an accepted warm start.
            :attr:`last_kind` says how it was found (``"from_scratch"``, ``"warm"`` or
            ``"reacquired"`` after a lost warm start).

        Raises:
            ValueError: wrong number of frames, a frame of the wrong shape or view (naming it).
            PoseEstimationError: a view shows no transducer feature (the track is then lost), or
                a failed verdict with ``options.raise_on_failure``.
        """
        t_start = time.perf_counter()
        frames = frames_for_views(frames, self.views)
        return self._update(frames, None, t_start)

    def track(self, pairs: Iterable, *, ready: Callable[[], bool] | None = None) -> Iterator[PoseResult]:
        """:meth:`update` of each frame pair of ``pairs`` (e.g. a live stream), yielded in order.

        Without ``fast`` this is ``update`` in a loop. With ``fast`` the stages overlap across pairs:
        while a pair is refined and judged on the calling thread, the next pair's regions are segmented
        and mapped on a worker thread, from the last pose accepted before it (one pair older than
        :meth:`update` would use; the region's margin covers the motion). After a lost track the
        prepared regions are dropped. Counters, :attr:`last_kind` and the results are as ``update``'s;
        the poses are the same as ``update``'s wherever the two regions are (docs/tracking.md).

        Args:
            pairs: an iterable of frame pairs, each as :meth:`update` takes it.
            ready: for a live source whose next pair may not have arrived, a callable that says whether
                taking the next pair now would not wait (e.g. a queue is not empty); when False the
                current pair is posed first. None: the next pair is always taken ahead.

        Returns:
            An iterator of :class:`~histostudy.pose.result.PoseResult`, one per pair.

        Raises:
            ValueError, PoseEstimationError: as :meth:`update`; the error ends the iteration at the pair
                that caused it, after the results of every pair before it.
        """
        if self._region is None:
            for frames in pairs:
                yield self.update(frames)
            return
        yield from pipelined_updates(self, pairs, ready)

    @stage("pose")  # update's and track's (a segmentation inside it is charged to segment)
    def _update(self, frames: list[Frame], prepared, t_start: float, slot: int = 0,
                parallel: bool | None = None) -> PoseResult:
        """One update on checked frames; ``prepared``: their regions made by ``RegionEstimator.prepare``
        from an earlier pose (fast warm path), or None (then prepared here, in map buffers ``slot``);
        ``parallel``: the warm refinement's kernels (``RegionEstimator.finish``)."""
        self.n_updates += 1
        was_tracking = self._last_pose is not None
        # A pose refused only for its views' agreement fitted each view: near the limit of a noisy
        # statistic, the next frames may accept it at the price of a warm update, not of an estimate
        # from scratch (docs/tracking.md, "Warm starts that hold").
        resume = not was_tracking and self._refused_pose is not None
        T_start = self._last_pose if was_tracking else self._refused_pose if resume else None
        self._refused_pose = None
        try:
            result: PoseResult | None = None
            kind: str | None = None
            if T_start is not None:
                self.n_resume_attempts += resume
                try:
                    result = self._warm(frames, T_start, prepared, slot, parallel)
                except PoseEstimationError:
                    result = None  # no feature in a view: the from-scratch estimate below says so again
                if result is not None and result.verdict.ok:
                    kind = "warm"
                    self.n_warm += 1
                    self.n_resumed += resume
                elif was_tracking:
                    self.n_lost += 1
                    self._last_pose = None
            if kind is None:
                kind = "reacquired" if was_tracking else "from_scratch"
                self.n_from_scratch += 1
                result = self._estimate(frames, None)
                if kind == "reacquired" and result.verdict.ok:
                    self.n_reacquired += 1
        except PoseEstimationError:
            self.n_failed += 1
            self._last_pose = None
            self.last_result, self.last_kind = None, None
            raise
        finally:
            self.update_seconds += time.perf_counter() - t_start
        assert result is not None
        self.last_result, self.last_kind = result, kind
        if result.verdict.ok:
            self.n_accepted += 1
            self._last_pose = np.array(result.T_carm_transducer, dtype=np.float64)
        else:
            self.n_failed += 1
            self._last_pose = None
            # the fit checks passed when the views' agreement was measured (verdict.py)
            if self.tracking_options is not None and self.tracking_options.resume_refused \
                    and result.verdict.view_disagreement_mm:
                self._refused_pose = np.array(result.T_carm_transducer, dtype=np.float64)
            if self.options.raise_on_failure:
                raise refused(result)
        return result

    def _warm(self, frames: list[Frame], T_start: np.ndarray, prepared, slot: int, parallel=None) -> PoseResult:
        """The warm start from ``T_start``: :meth:`_estimate`'s; with ``fast``, a refused first attempt
        is tried again on the same regions at the rescue scale from the refused pose (counted)."""
        region = self._region
        if region is None:
            return self._estimate(frames, T_start)
        if prepared is None:
            prepared = region.prepare(frames, T_start, self.rng, slot)
        result = self._count_stage_seconds(region.finish(prepared, T_start, parallel))
        if result.verdict.ok or region.rescue_scale is None:
            return result
        # The verdict's statistics read high on the coarse label grid (docs/tracking.md, "Warm
        # starts that hold"): the grid estimate_pose judges on decides before a re-acquisition,
        # which costs ten warm updates.
        self.n_rescue_attempts += 1
        rescued = region.prepare_rescue(prepared, self.rng)
        second = self._count_stage_seconds(region.finish(rescued, result.T_carm_transducer, parallel))
        self.n_rescued += bool(second.verdict.ok)
        return second

    def _count_stage_seconds(self, result: PoseResult) -> PoseResult:
        add_timings(self.stage_seconds, result.timings_s)
        return result

    def _estimate(self, frames: list[Frame], initial_pose) -> PoseResult:
        """An estimate on the whole frames: from scratch (``initial_pose`` None; at the label scale where
        there is a :class:`~._scratch.ScratchEstimator`), or warm from ``initial_pose`` without
        ``fast`` (:meth:`_warm` runs the fast warm path itself)."""
        if initial_pose is None and self._scratch is not None:
            return self._count_stage_seconds(self._scratch.estimate(frames, self.rng))
        # With ``fast``, a U-Net segments the full frames through UNetRunner.segment: its labels
        # (the checkpoint's upsampled arg-max, computed along the label edges only) in a
        # fraction of the time.
        segmenter = self.segmenter if self._region is None else self._region.full_frame_segmenter
        return self._count_stage_seconds(estimate_pose(frames, self.model, segmenter=segmenter,
                                                       orientation=self.orientation, rng=self.rng,
                                                       initial_pose=initial_pose, options=self._estimate_options))
