"""Tests of histostudy.pose.cost (with its kernels, cost._kernels, and its reference, cost._reference):
eq. 3 (numba against the numpy reference), the outside constant, absent classes, the analytic
Jacobian with the left perturbation of histostudy.pose.perturbation, and input validation."""

import numba
import numpy as np
import pytest

from histostudy.geometry import invert_transform, make_transform, transform_points
from histostudy.geometry.transforms import params_from_transform
from histostudy.imaging import View, default_biplane, render_labels
from histostudy.pose import DistanceMaps, PoseCost, apply_left_perturbation
from histostudy.pose.cost import OUTSIDE_DISTANCE_PX
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, pose_facing

T_TRUE = pose_facing(focal_point_mm=(5.0, -3.0, 8.0), axial_rotation_rad=0.3)


def class_masks(model, T, view):
    """Noise-free per-class masks: each class rasterised alone (no overlap priority)."""
    return {f: render_labels(model.only(f), T, view) == int(f) for f in FEATURE_CLASSES}


@pytest.fixture(scope="module")
def views():
    return default_biplane()


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


@pytest.fixture(scope="module")
def maps(views):
    fine = TransducerModel.build(spacing_mm=0.25)
    return [DistanceMaps(v, class_masks(fine, T_TRUE, v)) for v in views]


@pytest.fixture(scope="module")
def cost(model, maps):
    return PoseCost(model.points, maps)


def small_view(rows=60, cols=80):
    return View.from_gantry(0.0, 0.0, shape=(rows, cols), pixel_mm=4.0, name="small")


def pixel_points(view, pixels, depth_mm=785.0):
    """World points at ``depth_mm`` from the source that project exactly onto ``pixels`` (u, v)."""
    return view.source_mm + view.ray_directions(pixels) * depth_mm


# --- eq. 3 --------------------------------------------------------------------------------


def test_cost_is_zero_at_the_true_pose_of_exactly_rasterised_points_and_grows_off_it():
    view = small_view()
    rng = np.random.default_rng(2)
    masks, points = {}, {}
    T = pose_facing(view, (3.0, -2.0, 4.0), 0.7)
    for f in (Feature.TRANSDUCER, Feature.GAPS):
        pix = np.column_stack([rng.integers(5, 75, 200), rng.integers(5, 55, 200)]).astype(float)
        mask = np.zeros(view.shape, bool)
        mask[pix[:, 1].astype(int), pix[:, 0].astype(int)] = True
        masks[f] = mask
        points[f] = transform_points(invert_transform(T), pixel_points(view, pix, rng.uniform(700, 850, (200, 1))))
    cost = PoseCost(points, [DistanceMaps(view, masks)])
    assert cost(T) < 1e-16
    assert cost.reference_cost(T) < 1e-16
    for axis in range(6):
        delta = np.zeros(6)
        for size in (np.deg2rad(0.5), np.deg2rad(2.0)) if axis < 3 else (1.0, 4.0):
            delta[axis] = size
            assert cost(apply_left_perturbation(T, delta)) > 1e-3, (axis, size)
            assert cost(apply_left_perturbation(T, -delta)) > 1e-3, (axis, size)


def test_cost_of_the_rendered_transducer_is_smallest_at_the_true_pose(cost):
    at_truth = cost(T_TRUE)
    assert at_truth < 0.15  # sub-pixel rasterisation only: mean d² per class well under 0.1 px²
    for axis in range(6):
        delta = np.zeros(6)
        delta[axis] = np.deg2rad(1.0) if axis < 3 else 1.0
        assert cost(apply_left_perturbation(T_TRUE, delta)) > 2 * at_truth, axis


def test_numba_cost_matches_the_numpy_reference_and_is_thread_count_independent(cost, model, maps):
    rng = np.random.default_rng(3)
    reference = PoseCost(model.points, maps, backend="numpy")
    poses = [T_TRUE] + [apply_left_perturbation(T_TRUE, np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 20, 3)])
                        for _ in range(4)]
    poses.append(apply_left_perturbation(T_TRUE, [0, 0, 0, 150.0, 0, 0]))  # mostly outside the views
    for T in poses:
        fast, ref = cost(T), reference(T)
        assert fast == pytest.approx(ref, rel=1e-9)
        assert cost.reference_cost(T) == ref
        assert cost.terms(T).sum() == pytest.approx(ref, rel=1e-12)
    # 6 parameters and the 4x4 give the same number.
    assert cost(params_from_transform(poses[1])) == pytest.approx(cost(poses[1]), rel=1e-12)
    # Fixed blocks: the same bits whatever the number of threads, threaded or not.
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = [cost(T) for T in poses]
    finally:
        numba.set_num_threads(threads)
    assert one == [cost(T) for T in poses]
    serial, threaded = (PoseCost(model.points, maps, parallel=p) for p in (False, True))
    assert [serial(T) for T in poses] == [threaded(T) for T in poses] == one
    T = poses[1]
    a, b = serial.normal_equations(T), threaded.normal_equations(T)
    assert a.cost == b.cost and np.array_equal(a.JtJ, b.JtJ) and np.array_equal(a.Jtr, b.Jtr)
    ra, Ja = serial.residuals_and_jacobian(T)
    rb, Jb = threaded.residuals_and_jacobian(T)
    assert np.array_equal(ra, rb) and np.array_equal(Ja, Jb)


def test_outside_and_behind_source_points_cost_exactly_the_constant():
    view = small_view()
    labels = np.zeros(view.shape, np.uint8)
    labels[20:40, 20:60] = int(Feature.TRANSDUCER)
    dm = DistanceMaps(view, labels)
    far = pixel_points(view, np.array([[-0.51, 10.0], [80.0, 30.0], [40.0, -0.6], [40.0, 59.52]]))
    # Behind the source: in the plane of the image the sign flip of w would land these inside.
    behind = view.source_mm - (pixel_points(view, np.array([[30.0, 30.0], [50.0, 25.0]])) - view.source_mm)
    assert np.all(view.in_image(view.project(behind)))
    pts = np.vstack([far, behind])
    for backend in ("numba", "numpy"):
        for outside in (OUTSIDE_DISTANCE_PX, 0.5):
            cost = PoseCost({Feature.TRANSDUCER: pts}, [dm], outside_distance_px=outside, backend=backend)
            assert cost(np.eye(4)) == pytest.approx(outside ** 2, rel=1e-14)  # 0.01 per point / n_k
            r, J = cost.residuals_and_jacobian(np.eye(4))
            np.testing.assert_allclose(r, outside / np.sqrt(len(pts)), rtol=1e-14)
            assert not J.any()
    # The half-pixel rim belongs to the edge pixels (clamped), just beyond it is outside.
    rim = pixel_points(view, np.array([[-0.49, 30.0], [79.49, 30.0]]))
    cost = PoseCost({Feature.TRANSDUCER: rim}, [dm])
    edge = dm.maps[Feature.TRANSDUCER][30, [0, 79]].astype(float)
    assert cost(np.eye(4)) == pytest.approx(np.mean(edge ** 2), rel=1e-6)
    assert cost.reference_cost(np.eye(4)) == pytest.approx(np.mean(edge ** 2), rel=1e-6)


def test_classes_missing_from_a_view_are_dropped_there(model, maps, views):
    labels_a = np.zeros(views[0].shape, np.uint8)
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS):
        labels_a[maps[0].maps[f] == 0] = int(f)
    no_screws = DistanceMaps(views[0], labels_a)
    assert Feature.SCREWS in no_screws.absent
    cost = PoseCost(model.points, [no_screws, maps[1]])
    s = cost.classes.index(Feature.SCREWS)
    assert not cost.active[0, s] and cost.active[1, s] and cost.weights[0, s] == 0
    assert cost.terms(T_TRUE)[0, s] == 0
    # Moving the screws changes nothing in view A, where they are absent.
    moved = dict(model.points)
    moved[Feature.SCREWS] = model.points[Feature.SCREWS] + [30.0, -20.0, 10.0]
    only_a = PoseCost(model.points, [no_screws])
    assert PoseCost(moved, [no_screws])(T_TRUE) == only_a(T_TRUE)
    without = {f: p for f, p in model.points.items() if f != Feature.SCREWS}
    assert only_a(T_TRUE) == pytest.approx(PoseCost(without, [no_screws])(T_TRUE), rel=1e-12)
    # A one-view cost taken from the two-view one reads its maps from the shared buffer (both
    # views' stretches, with and without the screws) and gives the same bits as one built alone.
    T = apply_left_perturbation(T_TRUE, [0.01, -0.02, 0, 2.0, -1.0, 0.5])
    for i, m in enumerate([no_screws, maps[1]]):
        shared = cost.select_views(i)
        assert np.shares_memory(shared._maps, cost._maps)
        assert shared(T) == PoseCost(model.points, [m])(T)


def test_subset_and_select_views(cost):
    rng = np.random.default_rng(4)
    sub = cost.subset(500, rng)
    assert all(n == min(500, cost.n_points[f]) for f, n in sub.n_points.items())
    assert sub._maps is cost._maps  # the maps are shared, not copied
    T = apply_left_perturbation(T_TRUE, [0.01, 0, 0, 2.0, -1.0, 0])
    assert sub(T) == pytest.approx(cost(T), rel=0.2)
    per_view = [cost.select_views(i)(T) for i in range(2)]
    assert sum(per_view) == pytest.approx(cost(T), rel=1e-12)


def test_costs_at_translations_equal_one_call_per_pose(cost):
    sub = cost.subset(400, np.random.default_rng(5))
    R = apply_left_perturbation(T_TRUE, [0.02, -0.01, 0.03, 0, 0, 0])[:3, :3]
    translations = T_TRUE[:3, 3] + np.random.default_rng(6).normal(scale=20.0, size=(17, 3))
    batch = sub.costs_at_translations(R, translations)
    assert batch.shape == (17,)
    assert np.array_equal(batch, [sub(make_transform(R, t)) for t in translations])
    reference = PoseCost(sub.points, sub.maps, backend="numpy")
    assert np.allclose(reference.costs_at_translations(R, translations), batch, rtol=1e-5)
    with pytest.raises(ValueError, match="translations_mm"):
        sub.costs_at_translations(R, [[0.0, np.nan, 0.0]])
    with pytest.raises(ValueError, match="rotation"):
        sub.costs_at_translations(2 * R, translations)


@pytest.mark.parametrize("kernel_name", ["normal_serial", "cost_serial"])
def test_serial_kernels_release_the_gil_while_they_run(cost, kernel_name):
    # Tracker.track segments the next pair on a worker thread while this one is refined on the
    # calling thread: a kernel holding the GIL stalls the worker's Python between torch's
    # operations (docs/tracking.md, "Where it stands"). One long call: the cost's blocks, many times.
    import threading
    import time

    from histostudy.pose.cost import _kernels as cost_kernels

    kernel = getattr(cost_kernels, kernel_name)
    sub = cost.subset(300, np.random.default_rng(3))
    M, c = sub._folded(T_TRUE)
    R = np.ascontiguousarray(T_TRUE[:3, :3])
    tail = (sub._maps, sub._rows, sub._cols, sub.weights, OUTSIDE_DISTANCE_PX ** 2, np.inf)

    def run(tasks):
        if kernel_name == "normal_serial":
            return kernel(sub._pts, tasks, R, M, c, sub._P3, *tail)
        return kernel(sub._pts, tasks, M, c, *tail)

    run(sub._tasks)  # compiled before timing
    copies = np.tile(sub._tasks, (200, 1))

    def seconds_per_copy():
        t = time.perf_counter()
        run(copies)
        return (time.perf_counter() - t) / 200

    # the fastest of three sizes the call: one slowed by a busy machine would make it too short
    per_copy = min(seconds_per_copy() for _ in range(3))
    tasks = np.ascontiguousarray(np.tile(sub._tasks, (max(200, int(0.8 / per_copy)), 1)))
    worker = threading.Thread(target=run, args=(tasks,))
    ticks = []
    t0 = time.perf_counter()
    worker.start()
    while worker.is_alive():
        ticks.append(time.perf_counter())
    kernel_s = time.perf_counter() - t0
    gaps = np.diff([t0] + ticks)
    assert kernel_s > 0.3, kernel_s
    # held, the GIL would stop this loop for the whole call; released, only the scheduler pauses it
    assert gaps.max() < 0.5 * kernel_s, (gaps.max(), kernel_s)


def test_with_outside_distance_changes_only_the_off_map_constant(cost):
    T = T_TRUE.copy()
    T[:3, 3] += 300.0 * cost.views[0].detector_axes[0]  # most of the model off view A
    other = cost.with_outside_distance(25.0)
    assert other._maps is cost._maps and other.outside_distance_px == 25.0
    assert other(T) == PoseCost(cost.points, cost.maps, outside_distance_px=25.0)(T)
    assert other(T) > cost(T)


def test_capped_cost_equals_the_cost_on_truncated_maps_bit_for_bit(cost):
    """The kernels' cap is DistanceMaps.truncated without the copy: same cost, normal equations,
    residuals, Jacobian and grid costs, in both back-ends; a 2.5 px cap (not a float32 number)
    checks that the cap is rounded as the float32 maps are."""
    T = apply_left_perturbation(T_TRUE, [0.03, -0.02, 0.01, 4.0, -3.0, 2.0])
    for cap_px, outside in ((2.5, None), (30.0, 30.0)):
        capped = cost.capped(cap_px, outside_distance_px=outside)
        assert capped._maps is cost._maps and capped.max_distance_px == cap_px
        copied = PoseCost(cost.points, [m.truncated(cap_px) for m in cost.maps],
                          outside_distance_px=capped.outside_distance_px)
        assert capped(T) == copied(T)
        # Some points lie farther than the cap from their class.
        assert capped(T) < cost.with_outside_distance(capped.outside_distance_px)(T)
        a, b = capped.normal_equations(T), copied.normal_equations(T)
        assert a.cost == b.cost and np.array_equal(a.JtJ, b.JtJ) and np.array_equal(a.Jtr, b.Jtr)
        for x, y in zip(capped.residuals_and_jacobian(T), copied.residuals_and_jacobian(T)):
            assert np.array_equal(x, y)
        sub = capped.subset(300, np.random.default_rng(2))
        assert sub.max_distance_px == cap_px and sub.select_views(1).max_distance_px == cap_px
        ref = PoseCost(sub.points, [m.truncated(cap_px) for m in cost.maps],
                       outside_distance_px=sub.outside_distance_px)
        translations = T[:3, 3] + np.random.default_rng(3).normal(scale=10.0, size=(5, 3))
        assert np.array_equal(sub.costs_at_translations(T[:3, :3], translations),
                              ref.costs_at_translations(T[:3, :3], translations))
        numpy_capped = PoseCost(cost.points, cost.maps, max_distance_px=cap_px, backend="numpy",
                                outside_distance_px=capped.outside_distance_px)
        assert numpy_capped(T) == pytest.approx(copied.reference_cost(T), rel=1e-12)
        assert numpy_capped(T) == pytest.approx(capped(T), rel=1e-9)
    assert cost.capped(None) is cost and cost.capped(None)(T) == cost(T)
    assert cost.capped(5.0).capped(None)(T) == cost(T)


# --- Jacobian -----------------------------------------------------------------------------


def test_analytic_jacobian_matches_finite_differences(cost, model, maps):
    T = apply_left_perturbation(T_TRUE, [0.02, -0.01, 0.015, 1.5, -2.0, 1.0])
    r, J = cost.residuals_and_jacobian(T)
    r_ref, J_ref = cost.reference_residuals_and_jacobian(T)
    np.testing.assert_allclose(r, r_ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(J, J_ref, rtol=1e-7, atol=1e-12)
    assert np.dot(r, r) == pytest.approx(cost(T), rel=1e-9)

    h = np.array([1e-7] * 3 + [1e-5] * 3)  # rad, mm: ~1e-4 px, rarely across a pixel-cell edge
    fd = np.empty_like(J)
    for p in range(6):
        e = np.zeros(6)
        e[p] = h[p]
        plus, minus = cost.residuals(apply_left_perturbation(T, e)), cost.residuals(apply_left_perturbation(T, -e))
        fd[:, p] = (plus - minus) / (2 * h[p])
    scale = np.abs(J).max(axis=0)
    close = np.all(np.abs(fd - J) <= 1e-4 * scale, axis=1)
    assert close.mean() > 0.995, close.mean()  # the rest straddle a cell edge (kink of the interpolant)
    # The gradient of C is 2 J'r.
    ne = cost.normal_equations(T)
    assert ne.cost == pytest.approx(cost(T), rel=1e-12)
    np.testing.assert_allclose(ne.JtJ, J.T @ J, rtol=1e-9, atol=1e-12 * np.abs(ne.JtJ).max())
    np.testing.assert_allclose(ne.Jtr, J.T @ r, rtol=1e-9, atol=1e-12 * np.abs(ne.Jtr).max())
    grad_fd = np.array([(cost(apply_left_perturbation(T, np.eye(6)[p] * h[p]))
                         - cost(apply_left_perturbation(T, -np.eye(6)[p] * h[p]))) / (2 * h[p]) for p in range(6)])
    np.testing.assert_allclose(2 * ne.Jtr, grad_fd, rtol=2e-2, atol=1e-3 * np.abs(grad_fd).max())


# --- validation ---------------------------------------------------------------------------


def test_bad_inputs_raise_clear_errors(model, maps):
    view = small_view()
    with pytest.raises(ValueError, match="at least one DistanceMaps"):
        PoseCost(model.points, [])
    with pytest.raises(ValueError, match=r"points has an unknown class key 7"):
        PoseCost({7: np.zeros((3, 3))}, maps)
    with pytest.raises(ValueError, match="class_weights has an unknown class key"):
        PoseCost(model.points, maps, class_weights={"screws": 1.0})
    with pytest.raises(ValueError, match=r"class_weights\[GAPS\] must be finite and >= 0"):
        PoseCost(model.points, maps, class_weights={Feature.GAPS: -1.0})
    with pytest.raises(ValueError, match=r"points\[SCREWS\] must be a finite \(n, 3\)"):
        PoseCost({Feature.SCREWS: np.zeros((4, 2))}, maps)
    with pytest.raises(ValueError, match="outside_distance_px"):
        PoseCost(model.points, maps, outside_distance_px=-0.1)
    for bad in (0.0, -1.0, np.inf, True, "3"):
        with pytest.raises(ValueError, match="max_distance_px must be None or a finite number > 0"):
            PoseCost(model.points, maps, max_distance_px=bad)
    with pytest.raises(ValueError, match="backend"):
        PoseCost(model.points, maps, backend="cuda")
    with pytest.raises(ValueError, match="parallel must be"):
        PoseCost(model.points, maps, parallel="yes")
    empty = DistanceMaps(view, np.zeros(view.shape, np.uint8))
    with pytest.raises(ValueError, match="no class is both in the model"):
        PoseCost(model.points, [empty])
    cost = PoseCost(model.points, maps)
    with pytest.raises(ValueError, match="pose must be a 4x4"):
        cost(np.eye(3))
    with pytest.raises(ValueError, match="must be a proper rotation"):
        cost(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="n_per_class"):
        cost.subset(0, np.random.default_rng(0))
    with pytest.raises(TypeError, match="rng"):
        cost.subset(10, 0)
    with pytest.raises(ValueError, match="indices"):
        cost.select_views([2])
