"""The pose-estimation cost of §II-B.3 (eq. 3), its residuals and their Jacobian: :class:`PoseCost`,
the bilinear look-up of each view's distance maps at the projected model points. Poses are 4x4
``T_carm_transducer`` (mm), model points in mm in the transducer frame, distances in pixels; the
cost's definition, back-ends and Jacobian are in docs/pose-estimation.md, "The cost, eq. 3".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numba
import numpy as np

from histostudy.geometry import check_rigid, check_rotation, make_transform, transform_from_params
from histostudy.transducer import FEATURE_CLASSES, Feature

from ..distance_maps import DistanceMaps, feature_class
from ..perturbation import NormalEquations
from ._kernels import (
    BLOCK_POINTS,
    cost_parallel,
    cost_serial,
    costs_batch,
    normal_parallel,
    normal_serial,
    residual_parallel,
    residual_serial,
)
from ._reference import reference_distances, reference_sum_of_squares

__all__ = ["OUTSIDE_DISTANCE_PX", "PARALLEL_MIN_PROJECTIONS", "PoseCost"]

#: The paper's constant distance for points projected outside the distance map (§II-B.3).
OUTSIDE_DISTANCE_PX = 0.1

# Where the kernels' 21 sums of J^T J (its upper triangle, row by row) go in the symmetric 6x6
# matrix: computed once, not at each of the ~60 evaluations of a tracking update.
_UPPER = np.triu_indices(6)
_LOWER = (_UPPER[1], _UPPER[0])

#: Problems of at least this many point projections (blocks x BLOCK_POINTS) run on numba's threads
#: when ``PoseCost(parallel=None)``; smaller ones run on the calling thread.
PARALLEL_MIN_PROJECTIONS = 65536


class PoseCost:
    """Eq. 3 over one or more views, for a fixed model and fixed segmentations (§II-B.3).

    Args:
        points: ``{Feature: (n, 3)}`` model points in mm in the transducer frame (e.g.
            ``TransducerModel.build(spacing_mm=0.47).points``); empty classes are skipped.
        maps: one :class:`DistanceMaps` per view.
        class_weights: ``{Feature: lambda_k >= 0}``; default 1 for every class (the paper does not
            give its values). Classes left out of the dict weigh 1.
        outside_distance_px: the constant distance for points outside the map or behind the
            source (paper: 0.1 px).
        max_distance_px: beyond the paper: cap every map distance at this many pixels (None: eq. 3
            as written). The same numbers, bit for bit, as the cost on
            :meth:`DistanceMaps.truncated` maps, but applied as the kernels read the maps, so the
            ~50 MB of maps of a biplane pair are not copied for each cap (see :meth:`capped`).
        backend: ``"numba"`` (fused kernels, the default) or ``"numpy"`` (the float64 reference).
        parallel: run the numba kernels on numba's threads (True), on the calling thread (False),
            or decide by size (None: threads from :data:`PARALLEL_MIN_PROJECTIONS` projections on).
            Both give the same bits. Threads pay a start-up per call (small on an idle machine,
            but a whole scheduler time slice when another process holds a core), so small costs
            (subsets, grid searches) run serially; force False on a shared machine.

    Attributes:
        classes: the classes with points, in enum order (the "slots" of :attr:`weights`).
        n_points: ``{Feature: n_k}``.
        weights: ``(n_views, n_classes)`` float64 ``lambda_k / n_k``, 0 where the class is absent
            from that view's segmentation (it then contributes nothing there).
        active: ``(n_views, n_classes)`` bool, the classes that contribute in each view.

    Call it with a 4x4 ``T_carm_transducer`` or 6 parameters ``[rotvec (rad), t (mm)]``: it returns
    eq. 3's ``C`` in px² (float).

    Raises:
        TypeError: ``points`` is not a dict, or ``maps`` holds something other than
            :class:`~histostudy.pose.distance_maps.DistanceMaps`.
        ValueError: a class's points are not a finite ``(n, 3)`` array, no class has points,
            ``maps`` is empty, a class weight or ``outside_distance_px`` is negative or not finite,
            ``max_distance_px`` is not None or a finite number > 0, or ``backend`` / ``parallel``
            is not one of its choices.
    """

    def __init__(self, points: Mapping, maps: Sequence[DistanceMaps], *,
                 class_weights: Mapping | None = None, outside_distance_px: float = OUTSIDE_DISTANCE_PX,
                 max_distance_px: float | None = None, backend: str = "numba", parallel: bool | None = None,
                 _buffer=None):
        if not isinstance(points, Mapping):
            raise TypeError(f"points must be a dict {{Feature: (n, 3) array}}, got {type(points).__name__}")
        pts = {}
        for key, value in points.items():
            feature = feature_class(key, "points")
            arr = np.asarray(value, dtype=np.float64)
            if arr.size == 0:
                continue
            if arr.ndim != 2 or arr.shape[1] != 3 or not np.all(np.isfinite(arr)):
                raise ValueError(f"points[{feature.name}] must be a finite (n, 3) array in mm, got shape {arr.shape}")
            pts[feature] = arr
        if not pts:
            raise ValueError("points holds no points in any class; eq. 3 needs a model")
        maps = list(maps) if not isinstance(maps, DistanceMaps) else [maps]
        if not maps:
            raise ValueError("maps must hold at least one DistanceMaps (one per view), got none")
        for i, m in enumerate(maps):
            if not isinstance(m, DistanceMaps):
                raise TypeError(f"maps[{i}] must be a DistanceMaps, got {type(m).__name__}")
        lam = {f: 1.0 for f in FEATURE_CLASSES}
        for key, value in (class_weights or {}).items():
            feature = feature_class(key, "class_weights")
            value = float(value)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"class_weights[{feature.name}] must be finite and >= 0, got {value!r}")
            lam[feature] = value
        outside = float(outside_distance_px)
        if not np.isfinite(outside) or outside < 0:
            raise ValueError(f"outside_distance_px must be finite and >= 0, got {outside_distance_px!r}")
        if max_distance_px is not None:
            number = isinstance(max_distance_px, (int, float, np.integer, np.floating))
            if isinstance(max_distance_px, bool) or not number or not np.isfinite(max_distance_px) \
                    or max_distance_px <= 0:
                raise ValueError(f"max_distance_px must be None or a finite number > 0 (pixels), "
                                 f"got {max_distance_px!r}")
            max_distance_px = float(max_distance_px)
        if backend not in ("numba", "numpy"):
            raise ValueError(f"backend must be 'numba' or 'numpy', got {backend!r}")
        if parallel not in (None, True, False):
            raise ValueError(f"parallel must be None (automatic), True or False, got {parallel!r}")

        self.classes: tuple[Feature, ...] = tuple(f for f in FEATURE_CLASSES if f in pts)
        self.n_points = {f: len(pts[f]) for f in self.classes}
        self.points = {f: pts[f] for f in self.classes}
        self.maps = maps
        self.views = [m.view for m in maps]
        self.class_weights = {f: lam[f] for f in self.classes}
        self.outside_distance_px = outside
        self.max_distance_px = max_distance_px
        # The maps are float32: capping them at the float32 value of the cap is what
        # DistanceMaps.truncated does, so the kernels compare against the same number.
        self._cap = np.inf if max_distance_px is None else float(np.float32(max_distance_px))
        self.backend = backend
        self.parallel = parallel

        n_views, n_classes = len(maps), len(self.classes)
        self.active = np.array([[f in m.maps and lam[f] > 0 for f in self.classes] for m in maps], dtype=bool)
        if not self.active.any():
            raise ValueError(
                "no class is both in the model (with weight > 0) and segmented in any view: the cost "
                f"would be constant. Model classes {[f.name for f in self.classes]}, segmented: "
                f"{[[f.name for f in m.present] for m in maps]}"
            )
        self.weights = np.array([[lam[f] / self.n_points[f] for f in self.classes]] * n_views) * self.active

        # Pose-independent data, laid out once for the kernels.
        self._pts = np.ascontiguousarray(np.vstack([pts[f] for f in self.classes]))
        self._P = np.stack([v.P for v in self.views])  # (A, 3, 4)
        self._P3 = np.ascontiguousarray(self._P[:, :, :3])
        self._rows = np.array([v.shape[0] for v in self.views], dtype=np.int64)
        self._cols = np.array([v.shape[1] for v in self.views], dtype=np.int64)
        if _buffer is not None and _buffer[1].shape == self.active.shape and np.all((_buffer[1] >= 0) == self.active):
            self._maps, self._map_start = _buffer
        else:
            self._map_start = np.full((n_views, n_classes), -1, dtype=np.int64)
            chunks, pos = [], 0
            for a, m in enumerate(maps):
                for s, f in enumerate(self.classes):
                    if self.active[a, s]:
                        self._map_start[a, s] = pos
                        chunks.append(m.maps[f].ravel())
                        pos += m.maps[f].size
            self._maps = np.ascontiguousarray(np.concatenate(chunks), dtype=np.float32)
        # The kernels' work list: (view, class slot, map start, first point, end point) blocks.
        first = np.concatenate([[0], np.cumsum([self.n_points[f] for f in self.classes])])
        tasks = [(a, s, self._map_start[a, s], i0, min(i0 + BLOCK_POINTS, first[s + 1]))
                 for a in range(n_views) for s in range(n_classes) if self.active[a, s]
                 for i0 in range(first[s], first[s + 1], BLOCK_POINTS)]
        self._tasks = np.array(tasks, dtype=np.int64).reshape(-1, 5)

    # --- derived costs ----------------------------------------------------------------------

    def _use_threads(self) -> bool:
        if self.parallel is None:
            return numba.get_num_threads() > 1 and len(self._tasks) * BLOCK_POINTS >= PARALLEL_MIN_PROJECTIONS
        return self.parallel

    def _derive(self, points: dict, maps: list, view_indices=None) -> PoseCost:
        # Same maps and classes: share the flattened map buffer instead of copying ~50 MB again.
        shared = (self._maps, self._map_start) if maps is self.maps else None
        if view_indices is not None and len(view_indices) == 1 and self.active[view_indices[0]].any():
            # One view's maps are one contiguous stretch of the buffer: a view, not a copy.
            a = view_indices[0]
            starts = self._map_start[a]
            first = starts[self.active[a]].min()
            end = max(starts[s] + self.maps[a].maps[f].size for s, f in enumerate(self.classes) if self.active[a, s])
            shared = (self._maps[first:end], np.where(self.active[a], starts - first, -1)[None, :])
        return PoseCost(points, maps, class_weights=self.class_weights,
                        outside_distance_px=self.outside_distance_px, max_distance_px=self.max_distance_px,
                        backend=self.backend, parallel=self.parallel, _buffer=shared)

    def with_outside_distance(self, outside_distance_px: float) -> PoseCost:
        """The same cost with another constant distance for points off the map (eq. 3's 0.1 px);
        the distance maps are shared, not copied."""
        return self.capped(self.max_distance_px, outside_distance_px)

    def capped(self, max_distance_px: float | None, outside_distance_px: float | None = None) -> PoseCost:
        """The same points and maps with the distances capped at ``max_distance_px`` (None: no cap)
        and, if given, another constant for points off the map; the maps are shared, not copied.

        A cap bounds what a model point on a missed or spurious feature can add, so a few of them
        cannot pull the pose (beyond the paper; :func:`histostudy.pose.estimate_pose` caps its
        searches, refinement and verdict). Asked for what it already is, the cost returns itself."""
        outside = self.outside_distance_px if outside_distance_px is None else outside_distance_px
        if max_distance_px == self.max_distance_px and outside == self.outside_distance_px:
            return self
        return PoseCost(self.points, self.maps, class_weights=self.class_weights, outside_distance_px=outside,
                        max_distance_px=max_distance_px, backend=self.backend, parallel=self.parallel,
                        _buffer=(self._maps, self._map_start))

    def subset(self, n_per_class: int, rng: np.random.Generator) -> PoseCost:
        """A cheaper cost on at most ``n_per_class`` points of each class, drawn without replacement.

        The normalisation by ``n_k`` makes it an unbiased estimate of the full cost's per-class
        means, so it can stand in for it in a coarse first pass (grid search, coarse-to-fine LM).
        The distance maps are shared, not recomputed.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        n = int(n_per_class)
        if n != n_per_class or n < 1:
            raise ValueError(f"n_per_class must be a positive integer, got {n_per_class!r}")
        sub = {}
        for f in self.classes:
            p = self.points[f]
            sub[f] = p if len(p) <= n else p[np.sort(rng.choice(len(p), size=n, replace=False))]
        return self._derive(sub, self.maps)

    def select_views(self, indices) -> PoseCost:
        """The cost over a subset of the views (e.g. one view for the per-plane grid search, §II-B.4)."""
        idx: list[int] = []
        for i in [indices] if np.isscalar(indices) else list(indices):
            if not (isinstance(i, (int, np.integer)) and 0 <= i < len(self.maps)):
                raise ValueError(f"indices must be view indices in [0, {len(self.maps)}), got {indices!r}")
            idx.append(int(i))
        return self._derive(self.points, [self.maps[i] for i in idx], view_indices=idx)

    # --- evaluation -------------------------------------------------------------------------

    def _pose(self, pose) -> np.ndarray:
        arr = np.asarray(pose, dtype=np.float64)
        if arr.shape == (4, 4):
            return check_rigid(arr, "pose")
        if arr.size == 6 and arr.ndim == 1:
            return transform_from_params(arr)
        raise ValueError(f"pose must be a 4x4 T_carm_transducer or 6 parameters [rotvec (rad), t (mm)], "
                         f"got shape {arr.shape}")

    def _folded(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per view ``M = P3 R`` and ``c = P3 t + P[:, 3]``: ``[u w, v w, w] = M p + c``."""
        R, t = T[:3, :3], T[:3, 3]
        M = np.ascontiguousarray(self._P3 @ R)
        c = np.ascontiguousarray(self._P3 @ t + self._P[:, :, 3])
        return M, c

    def __call__(self, pose) -> float:
        """C (eq. 3) at ``pose`` (4x4 or 6 parameters)."""
        T = self._pose(pose)
        if self.backend == "numpy":
            return float(self._reference_terms(T).sum())
        M, c = self._folded(T)
        kernel = cost_parallel if self._use_threads() else cost_serial
        return float(kernel(self._pts, self._tasks, M, c, self._maps, self._rows, self._cols, self.weights,
                            self.outside_distance_px ** 2, self._cap))

    def costs_at_translations(self, R, translations_mm) -> np.ndarray:
        """C (eq. 3) at the poses ``(R, t)`` for each row ``t`` of ``translations_mm`` (n, 3): a grid
        search's nodes in one call, the rotation checked and folded into the projections once."""
        R = check_rotation(R, "R")
        t = np.asarray(translations_mm, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(t)):
            raise ValueError("translations_mm must be finite (n, 3) mm")
        if self.backend == "numpy" or len(t) == 0:
            return np.array([self(make_transform(R, ti)) for ti in t], dtype=np.float64)
        M = np.ascontiguousarray(self._P3 @ R)
        # Folded exactly as :meth:`_folded` does, so that each cost is the bits of a single call.
        c_all = np.ascontiguousarray([self._P3 @ ti + self._P[:, :, 3] for ti in t]).reshape(len(t), -1, 3)
        return costs_batch(self._pts, self._tasks, M, c_all, self._maps, self._rows, self._cols, self.weights,
                            self.outside_distance_px ** 2, self._cap)

    def reference_cost(self, pose) -> float:
        """C (eq. 3) by the plain numpy float64 reference, whatever the backend."""
        return float(self._reference_terms(self._pose(pose)).sum())

    def terms(self, pose) -> np.ndarray:
        """``(n_views, n_classes)`` contributions ``lambda_k / n_k * sum_i d²`` (numpy reference); they sum to C."""
        return self._reference_terms(self._pose(pose))

    def _reference_terms(self, T: np.ndarray) -> np.ndarray:
        out = np.zeros(self.weights.shape)
        for a in range(len(self.maps)):
            for s, f in enumerate(self.classes):
                if not self.active[a, s]:
                    continue
                total = reference_sum_of_squares(T, self._P3[a], self._P[a, :, 3], self.maps[a].maps[f],
                                                 self.points[f], self.outside_distance_px, self._cap)
                out[a, s] = self.weights[a, s] * total
        return out

    def residuals(self, pose) -> np.ndarray:
        """``(n_views * N,)`` weighted residuals ``sqrt(lambda_k / n_k) d`` (numpy reference), view-major,
        points in the order of :attr:`classes`; ``sum r² = C``."""
        return self.reference_residuals_and_jacobian(pose, jacobian=False)[0]

    def reference_residuals_and_jacobian(self, pose, jacobian: bool = True):
        """Numpy float64 reference of :meth:`residuals_and_jacobian` (``J`` is None without ``jacobian``)."""
        T = self._pose(pose)
        rs, Js = [], []
        for a in range(len(self.maps)):
            for s, f in enumerate(self.classes):
                n = self.n_points[f]
                if not self.active[a, s]:
                    rs.append(np.zeros(n))
                    Js.append(np.zeros((n, 6)))
                    continue
                sw = np.sqrt(self.weights[a, s])
                out = reference_distances(T, self._P3[a], self._P[a, :, 3], self.maps[a].maps[f], self.points[f],
                                          self.outside_distance_px, self._cap, jacobian=jacobian)
                if jacobian:
                    d, J = out
                    Js.append(sw * J)
                else:
                    d = out
                rs.append(sw * d)
        return np.concatenate(rs), (np.vstack(Js) if jacobian else None)

    def residuals_and_jacobian(self, pose) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``r`` ``(n_views * N,)`` and their Jacobian ``(n_views * N, 6)`` with respect to the
        left perturbation ``[w (rad), v (mm)]`` about the focal point (docs/pose-estimation.md).

        ``r = sqrt(lambda_k / n_k) * d`` view-major, points in the order of :attr:`classes`
        (``sum r² = C``; outside points carry the constant and a zero row; absent classes 0).
        Materialises the n x 6 Jacobian (fused numba kernel, or the numpy reference with
        ``backend="numpy"``); the refinement uses :meth:`normal_equations`, which does not.
        """
        T = self._pose(pose)
        if self.backend == "numpy":
            return self.reference_residuals_and_jacobian(T)
        M, c = self._folded(T)
        n_views, n = len(self.maps), len(self._pts)
        r = np.zeros((n_views, n))
        J = np.zeros((n_views, n, 6))
        kernel = residual_parallel if self._use_threads() else residual_serial
        kernel(self._pts, self._tasks, np.ascontiguousarray(T[:3, :3]), M, c, self._P3, self._maps,
               self._rows, self._cols, self.weights, self.outside_distance_px, self._cap, r, J)
        return r.reshape(-1), J.reshape(-1, 6)

    def normal_equations(self, pose) -> NormalEquations:
        """C, ``J^T J`` and ``J^T r`` at ``pose`` in one fused pass (nothing of size n x 6 is built).

        With ``backend="numpy"`` they are formed from the materialised reference Jacobian.
        """
        return self._normal_equations(self._pose(pose))

    def _normal_equations(self, T: np.ndarray) -> NormalEquations:
        """:meth:`normal_equations` at a pose already checked: a float64 4x4 rigid ``T`` (the
        Levenberg-Marquardt loop's steps, :func:`~histostudy.pose.perturbation.apply_left_perturbation`
        of a checked pose, which skip the :func:`~histostudy.geometry.check_rigid` of every step)."""
        if self.backend == "numpy":
            r, J = self.reference_residuals_and_jacobian(T)
            return NormalEquations(float(r @ r), J.T @ J, J.T @ r)
        M, c = self._folded(T)
        kernel = normal_parallel if self._use_threads() else normal_serial
        acc = kernel(self._pts, self._tasks, np.ascontiguousarray(T[:3, :3]), M, c, self._P3, self._maps,
                     self._rows, self._cols, self.weights, self.outside_distance_px ** 2, self._cap)
        JtJ = np.empty((6, 6))
        JtJ[_UPPER] = acc[1:22]
        JtJ[_LOWER] = acc[1:22]
        return NormalEquations(float(acc[0]), JtJ, acc[22:28].copy())

    @property
    def n_total(self) -> int:
        """Number of model points (all classes)."""
        return len(self._pts)

    def __repr__(self) -> str:
        counts = ", ".join(f"{f.name}={n}" for f, n in self.n_points.items())
        cap = "" if self.max_distance_px is None else f", max_distance_px={self.max_distance_px:g}"
        return f"PoseCost({len(self.maps)} views, {counts}{cap}, backend={self.backend!r})"
