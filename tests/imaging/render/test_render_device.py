"""Tests of the splatting renderers beside the numpy reference: histostudy.imaging.render._device,
_splat_kernels (compiled, CPU) and _torch (torch, here on the CPU; the CUDA code is the same).

The renderers draw the same distribution, not the same numbers, so they are held to:
- the reference's image exactly (float tolerance) where nothing is drawn (zero jitter), on every
  class and every background;
- the reference's image exactly when the compiled kernel's own normals are fed to the reference's
  arithmetic;
- in distribution, an image that differs from a reference image no more than a second reference
  image does; a standard normal by scipy's Kolmogorov-Smirnov test.
"""

import numba
import numpy as np
import pytest
import torch
from scipy import stats

from histostudy.imaging import (
    View,
    add_poisson_noise,
    default_biplane,
    random_background,
    render_frame,
    render_labels,
    render_line_integrals,
)
from histostudy.imaging.render import TorchSplatter, poisson_noise_torch
from histostudy.imaging.render._device import check_device, splat_compiled, splat_points
from histostudy.imaging.render._reference import _nearest_pixel
from histostudy.imaging.render._splat_kernels import _R, standard_normals
from histostudy.transducer import Feature, TransducerModel, pose_facing


@pytest.fixture(scope="module")
def model():
    return TransducerModel.build(spacing_mm=0.47)


@pytest.fixture(scope="module")
def view():
    return default_biplane()[0]


def _torch_cpu(model, T, view, seed, sigma=0.5, n_splats=16):
    splatter = TorchSplatter(model, "cpu", n_splats=n_splats, splat_sigma_mm=sigma)
    return splatter.line_integrals([T], [view], [seed])[0].numpy()


# --- the compiled kernel's normals ----------------------------------------------------------


def test_compiled_normals_are_standard_normal():
    x = standard_normals(11, 2000, 500).ravel().astype(np.float64)
    assert stats.kstest(x, "norm").pvalue > 0.01
    assert abs(x.mean()) < 5 / np.sqrt(x.size) and abs(x.var() - 1) < 5 * np.sqrt(2 / x.size)
    # the ziggurat's tail beyond r is drawn by a separate method: its share must be the normal's
    tail = np.mean(np.abs(x) > _R)
    expected = 2 * stats.norm.sf(_R)
    assert abs(tail - expected) < 5 * np.sqrt(expected / x.size)
    # and it lies where it should (the tail draws are beyond r, symmetric)
    beyond = x[np.abs(x) > _R]
    assert stats.kstest(np.abs(beyond), lambda v: 1 - stats.norm.sf(v) / stats.norm.sf(_R)).pvalue > 0.01


def test_each_points_normals_are_its_own_and_seeded():
    a = standard_normals(3, 100, 48)
    assert np.array_equal(a, standard_normals(3, 100, 48))
    assert np.array_equal(a[:40], standard_normals(3, 40, 48))       # a point's stream ignores the others
    assert not np.array_equal(a, standard_normals(4, 100, 48))
    assert abs(np.corrcoef(a[:-1].ravel(), a[1:].ravel())[0, 1]) < 0.05  # neighbouring points uncorrelated


# --- exact where the draws agree ------------------------------------------------------------


@pytest.mark.parametrize("renderer", ["compiled", "torch"])
def test_zero_jitter_gives_the_references_image(model, view, renderer):
    T = pose_facing()
    rng_seed = 5
    reference = render_line_integrals(model, T, view, rng=np.random.default_rng(rng_seed), splat_sigma_mm=0.0)
    if renderer == "compiled":
        image = render_line_integrals(model, T, view, rng=np.random.default_rng(rng_seed), splat_sigma_mm=0.0,
                                      device="cpu")
    else:
        image = _torch_cpu(model, T, view, seed=1, sigma=0.0)
    assert image.dtype == np.float32 and image.shape == view.shape
    np.testing.assert_allclose(image, reference, rtol=2e-6, atol=1e-6 * reference.max())
    assert reference.max() > 1.0


@pytest.mark.parametrize("feature", list(Feature)[1:])
def test_zero_jitter_matches_on_every_class(model, view, feature):
    """One class at a time: a model whose other classes weigh nothing (the gaps, air, weigh nothing)."""
    only = TransducerModel(spec=model.spec, spacing_mm=model.spacing_mm, points=model.points,
                           weights={f: (w if f == feature else np.zeros_like(w)) for f, w in model.weights.items()},
                           grid_step_mm=model.grid_step_mm)
    T = pose_facing()
    reference = render_line_integrals(only, T, view, rng=np.random.default_rng(0), splat_sigma_mm=0.0)
    assert (reference.max() > 0) == bool((model.weights[feature] > 0).any())
    for image in (render_line_integrals(only, T, view, rng=np.random.default_rng(0), splat_sigma_mm=0.0, device="cpu"),
                  _torch_cpu(only, T, view, seed=0, sigma=0.0)):
        np.testing.assert_allclose(image, reference, rtol=2e-6, atol=1e-6 * reference.max())


def test_compiled_kernel_is_the_references_arithmetic_on_its_own_normals(model, view):
    """The reference's projection and binning, fed the kernel's normals, give the kernel's image."""
    T = pose_facing()
    n_splats, sigma, seed = 16, 0.5, 123
    image = splat_compiled(model, T, view, seed=seed, n_splats=n_splats, splat_sigma_mm=sigma)
    uvw, values = splat_points(model, T, view, n_splats)

    # stream i is point i of the classes in enum order; the reference keeps the weighted points in front
    points, weights = model.all_points()[0], model.all_weights()
    world = points @ T[:3, :3].T + T[:3, 3]
    kept = np.flatnonzero((weights > 0) & (view.project_homogeneous(world)[:, 2] > 0))
    assert len(kept) == len(values)
    offsets = standard_normals(seed, len(weights), 3 * n_splats)[kept].reshape(len(kept), n_splats, 3)
    offsets = np.moveaxis(offsets, 2, 0) * np.float32(sigma)             # (3, m, n), component-major
    M = view.P[:, :3].astype(np.float32)
    h = np.einsum("ij,jmn->imn", M, offsets) + uvw.T.astype(np.float32)[:, :, None]
    flat, ok = _nearest_pixel(h[0], h[1], h[2], *view.shape)
    expected = np.bincount(flat, weights=np.broadcast_to(values[:, None], ok.shape)[ok],
                           minlength=view.shape[0] * view.shape[1]).reshape(view.shape)
    # a copy within float32 rounding of a pixel edge may land on the other side in one of the two
    moved = np.abs(image - expected) > 1e-4 * values.max()
    assert moved.sum() <= 1e-5 * ok.sum()
    np.testing.assert_allclose(image[~moved], expected[~moved], rtol=1e-5, atol=1e-9)


# --- in distribution -------------------------------------------------------------------------


def _one_point_model(model, where_mm):
    empty = {f: np.zeros((0, 3)) for f in model.points}
    weights = {f: np.zeros(0) for f in model.points}
    empty[Feature.TRANSDUCER], weights[Feature.TRANSDUCER] = np.atleast_2d(where_mm), np.ones(1)
    return TransducerModel(spec=model.spec, spacing_mm=model.spacing_mm, points=empty, weights=weights)


@pytest.mark.parametrize("renderer", ["numpy", "compiled", "torch"])
def test_a_points_copies_spread_as_the_projected_gaussian(model, view, renderer):
    """200,000 copies of one point: their mass's mean and covariance in pixels are the projected
    jitter's, ``sigma² J Jᵀ`` (J the projection's Jacobian at the point) plus a pixel's 1/12."""
    where = np.array([4.0, -3.0, 2.0])
    point = _one_point_model(model, where)
    n, sigma, T = 200_000, 0.5, np.eye(4)
    if renderer == "torch":
        splatter = TorchSplatter(point, "cpu", n_splats=n, splat_sigma_mm=sigma)
        image = splatter.line_integrals([T], [view], [5])[0].numpy()
    else:
        image = render_line_integrals(point, T, view, rng=np.random.default_rng(5), n_splats=n, splat_sigma_mm=sigma,
                                      device=None if renderer == "numpy" else "cpu")
    rows, cols = np.nonzero(image)
    mass = image[rows, cols].astype(np.float64)
    xy = np.stack([cols, rows], axis=1).astype(np.float64)
    mean = mass @ xy / mass.sum()
    cov = ((xy - mean) * mass[:, None]).T @ (xy - mean) / mass.sum()

    u, v, w = view.P @ np.append(where, 1.0)
    J = (view.P[:2, :3] * w - np.outer([u, v], view.P[2, :3])) / w**2
    expected = sigma**2 * J @ J.T + np.eye(2) / 12.0
    np.testing.assert_allclose(mean, [u / w, v / w], atol=0.02)
    np.testing.assert_allclose(cov, expected, rtol=0.02, atol=0.02 * expected[0, 0])


def test_compiled_image_is_seeded_and_independent_of_the_thread_count(model, view):
    T = pose_facing()
    a = render_line_integrals(model, T, view, rng=np.random.default_rng(9), device="cpu")
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        b = render_line_integrals(model, T, view, rng=np.random.default_rng(9), device="cpu")
    finally:
        numba.set_num_threads(threads)
    c = render_line_integrals(model, T, view, rng=np.random.default_rng(10), device="cpu")
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_torch_frames_depend_on_their_seed_not_their_batch(model, view):
    splatter = TorchSplatter(model, "cpu")
    T1, T2 = pose_facing(), pose_facing()
    T2[:3, 3] += [3.0, -2.0, 5.0]
    batch = splatter.line_integrals([T1, T2], [view, view], [7, 8])
    alone = splatter.line_integrals([T2], [view], [8])
    assert batch.shape == (2, *view.shape)
    assert torch.equal(batch[1], alone[0]) and not torch.equal(batch[0], batch[1])


def test_torch_noise_has_the_references_statistics():
    p = np.full((200, 300), 2.0)
    reference = add_poisson_noise(p, 5e3, np.random.default_rng(0))
    noisy = poisson_noise_torch(torch.as_tensor(p), 5e3, seed=0).numpy()
    assert noisy.dtype == np.float32
    sd = reference.std()
    assert abs(noisy.mean() - reference.mean()) < 5 * sd / np.sqrt(p.size)
    assert abs(noisy.std() / sd - 1) < 0.02
    # a zero count takes the reference's clamp
    dark = poisson_noise_torch(torch.full((10, 10), 50.0), 5e3, seed=1).numpy()
    np.testing.assert_allclose(dark, -np.log(0.5 / 5e3), rtol=1e-6)


# --- frames ---------------------------------------------------------------------------------


@pytest.mark.parametrize("background", ["none", "array", "abdomen", "phantom"])
def test_frames_on_the_compiled_renderer_match_on_every_background(model, view, background):
    rng = np.random.default_rng(4)
    scene = {"none": None, "array": rng.uniform(0, 3, view.shape),
             "abdomen": random_background(rng, "abdomen"), "phantom": random_background(rng, "phantom")}[background]
    T = pose_facing()
    kwargs = dict(background=scene, photons_per_pixel=None, splat_sigma_mm=0.0)
    reference = render_frame(model, T, view, rng=np.random.default_rng(0), **kwargs)
    frame = render_frame(model, T, view, rng=np.random.default_rng(0), device="cpu", **kwargs)
    np.testing.assert_allclose(frame.image, reference.image, rtol=2e-6, atol=1e-5)
    assert np.array_equal(frame.labels, reference.labels)
    assert frame.meta["splat_device"] == "cpu" and reference.meta["splat_device"] == "numpy"


def test_a_noisy_frame_renders_on_the_compiled_renderer(model, view):
    frame = render_frame(model, pose_facing(), view, rng=np.random.default_rng(0), device="cpu")
    again = render_frame(model, pose_facing(), view, rng=np.random.default_rng(0), device="cpu")
    assert np.array_equal(frame.image, again.image) and np.all(np.isfinite(frame.image))
    assert np.array_equal(frame.labels, render_labels(model, pose_facing(), view))


@pytest.mark.parametrize("seed", range(4))
def test_compiled_labels_are_the_references(model, seed):
    """Random §II-B.2 training poses and views: the compiled projection paints the same labels (a
    point within float64 rounding of a pixel edge could differ; none has on these)."""
    from histostudy.learning import HybridFrames
    from histostudy.learning.datasets import random_training_pose

    frames = HybridFrames("train", 3)
    view = frames.view(seed)
    T = random_training_pose(np.random.default_rng(seed), view)
    reference = render_labels(model, T, view)
    labels = render_labels(model, T, view, device="cpu")
    assert (reference > 0).sum() > 10_000
    assert (labels != reference).sum() <= 1e-5 * (reference > 0).sum()


# --- bad input -------------------------------------------------------------------------------


@pytest.mark.parametrize("device", ["gpu", "cuda:x", 0, "CPU"])
def test_an_unknown_device_is_refused_naming_it(model, view, device):
    with pytest.raises(ValueError, match="device must be"):
        render_frame(model, pose_facing(), view, rng=np.random.default_rng(0), device=device)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_a_gpu_is_refused_before_any_work(model, view):
    with pytest.raises(ValueError, match="no CUDA device"):
        check_device("cuda")
    with pytest.raises(ValueError, match="no CUDA device"):
        TorchSplatter(model, "cuda")


def test_torch_batches_are_checked(model, view):
    splatter = TorchSplatter(model, "cpu")
    other = View.from_gantry(30.0, 0.0, shape=(100, 120))
    with pytest.raises(ValueError, match="as long"):
        splatter.line_integrals([pose_facing()], [view, view], [1])
    with pytest.raises(ValueError, match="one detector shape"):
        splatter.line_integrals([pose_facing()] * 2, [view, other], [1, 2])
    with pytest.raises(ValueError, match="seeds must be"):
        splatter.line_integrals([pose_facing()], [view], [-1])
    with pytest.raises(ValueError, match="T_carm_transducer"):
        splatter.line_integrals([np.eye(3)], [view], [1])
