"""Tests of histostudy.imaging.rtk_projector (RTK's Joseph projector) against independent references.

Geometry: blob centroids against View.project; magnitude: a box's analytic chord lengths (slab
method); voxelisation: totals, centres of mass and a flat sheet's mu t / cos(incidence). Loading
itk-rtk costs ~30 s of CPU once per session (in the first test that needs it, not at collection).
"""

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_about_axis
from histostudy.imaging import Frame, View, render_labels
from histostudy.imaging import rtk_projector as rp
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, TransducerSpec, pose_facing

itk = pytest.importorskip("itk")  # rtk_projector imports itk only when it projects

# SWIG's wrappers of ITK warn on import under Python >= 3.12-style checks; nothing of ours.
pytestmark = pytest.mark.filterwarnings("ignore:builtin type .* has no __module__ attribute:DeprecationWarning")

SHAPE = (120, 160)
PIXEL = 0.308 * 8  # the 960x1240 detector at 1/8 the resolution: same field of view
THREADS = 1  # the machine is shared; these volumes are small


@pytest.fixture(scope="module", autouse=True)
def rtk_loaded():
    if not rp.rtk_available():
        pytest.skip("itk-rtk (itk.RTK, JosephForwardProjectionImageFilter) cannot be loaded")


def _hand_view() -> View:
    """A calibrated-style view built by hand: tilted detector, off-centre principal point,
    non-square pixels, principal ray missing the isocentre."""
    R = rotation_about_axis([0.3, 0.2, 1.0], 0.9) @ rotation_about_axis([1, 0, 0], np.pi / 2)
    e_w = R[2]
    source = -790.0 * e_w + np.array([6.0, -4.0, 9.0])
    f = 1180.0 / PIXEL
    K = np.array([[f, 0.0, 41.3], [0.0, 1.08 * f, 83.6], [0.0, 0.0, 1.0]])
    P = K @ np.hstack([R, (-R @ source)[:, None]])
    return View.from_matrix(P, shape=SHAPE, pixel_mm=PIXEL, name="hand")


def _views() -> list[View]:
    views = [View.from_gantry(a, b, shape=SHAPE, pixel_mm=PIXEL) for a, b in ((-60, 10), (0, 0), (45, -25))]
    return views + [_hand_view()]


def _ball(centre, radius=5.0, voxel=0.5):
    """A supersampled solid ball of mu 1/mm on a grid centred on ``centre``."""
    n = int(np.ceil(radius / voxel)) + 3
    ax = (np.arange(2 * n + 1) - n) * voxel
    z, y, x = np.meshgrid(ax, ax, ax, indexing="ij")
    mu = np.zeros(x.shape)
    sub = ((np.arange(4) + 0.5) / 4 - 0.5) * voxel
    for a in sub:
        for b in sub:
            for c in sub:
                mu += (x + a) ** 2 + (y + b) ** 2 + (z + c) ** 2 <= radius ** 2
    return (mu / 64).astype(np.float32), np.asarray(centre, float) - n * voxel, voxel


def _model(points, weights, feature=Feature.TRANSDUCER) -> TransducerModel:
    pts = {f: np.zeros((0, 3)) for f in FEATURE_CLASSES}
    wts = {f: np.zeros(0) for f in FEATURE_CLASSES}
    pts[feature], wts[feature] = np.asarray(points, float), np.asarray(weights, float)
    return TransducerModel(spec=TransducerSpec(), spacing_mm=0.25, points=pts, weights=wts)


# --- geometry -------------------------------------------------------------------------------


def test_hand_view_is_what_it_claims():
    K, _, _ = _hand_view().decomposition
    assert abs(K[0, 2] - 41.3) < 1e-6 and abs(K[1, 1] / K[0, 0] - 1.08) < 1e-9


@pytest.mark.parametrize("centre", [(0.0, 0.0, 0.0), (30.0, -20.0, 15.0), (-25.0, 40.0, -35.0)])
def test_blob_centroid_is_view_project_of_its_centre(centre):
    views = _views()
    images = rp.forward_project(_ball(centre), views, n_threads=THREADS)
    rows, cols = np.mgrid[:SHAPE[0], :SHAPE[1]]
    for view, image in zip(views, images):
        assert image.shape == SHAPE and image.dtype == np.float32
        total = image.sum(dtype=np.float64)
        centroid = np.array([(image * cols).sum() / total, (image * rows).sum() / total])
        expected = view.project(centre)[0]
        assert np.all(np.abs(centroid - expected) < 0.1), (view, centroid, expected)
        # A ball of radius 5 mm: the peak is its diameter (mu = 1/mm), the blob a few pixels wide.
        assert 9.0 < image.max() < 10.5


def test_geometry_has_one_projection_per_view_with_the_source_of_p():
    views = _views()
    geometry = rp.rtk_geometry(views)
    assert len(geometry.GetGantryAngles()) == len(views)
    for i, view in enumerate(views):
        source = np.array([geometry.GetSourcePosition(i)[k] for k in range(3)])
        np.testing.assert_allclose(source, view.source_mm, atol=1e-6)


# --- magnitude ------------------------------------------------------------------------------


def _chord(source, direction, lo, hi) -> float:
    with np.errstate(divide="ignore"):
        t1, t2 = (lo - source) / direction, (hi - source) / direction
    near, far = np.minimum(t1, t2).max(), np.maximum(t1, t2).min()
    return max(0.0, far - near)


@pytest.mark.parametrize("view", _views(), ids=lambda v: repr(v))
def test_uniform_box_gives_mu_times_chord_length(view):
    mu0, pitch, pad = 0.02, 1.0, 2
    n_xyz = np.array([60, 40, 50])
    mu = np.zeros(tuple((n_xyz + 2 * pad)[::-1]), np.float32)
    mu[pad:-pad, pad:-pad, pad:-pad] = mu0
    centre = np.array([10.0, -5.0, 8.0])
    origin = centre - (n_xyz + 2 * pad - 1) / 2 * pitch
    # Voxels are cubes for the line integral of a trilinear interpolant: faces half a voxel out.
    lo, hi = centre - n_xyz / 2 * pitch, centre + n_xyz / 2 * pitch
    image = rp.forward_project((mu, origin, pitch), view, n_threads=THREADS)[0]
    u0, v0 = np.round(view.project(centre)[0]).astype(int)
    for du, dv in ((0, 0), (5, -3), (-7, 6), (9, 8)):
        u, v = u0 + du, v0 + dv
        expected = mu0 * _chord(view.source_mm, view.ray_directions([[u, v]])[0], lo, hi)
        assert expected > 0.5
        assert abs(image[v, u] / expected - 1) < 0.02, (u, v, image[v, u], expected)


# --- voxelisation ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def coarse():
    digital = TransducerModel.build(spacing_mm=2.0)
    physical = TransducerModel.build_physical(spacing_mm=2.0, rng=np.random.default_rng(0))
    return digital, physical


POSE = pose_facing((0.15, 1.0, 0.25), focal_point_mm=(4.0, -6.0, 8.0))


@pytest.mark.parametrize("smooth", [True, False])
def test_voxelised_total_and_centre_of_mass_are_the_models(coarse, smooth):
    _, physical = coarse
    mu, origin, voxel = rp.voxelise_model(physical, POSE, voxel_mm=1.0, smooth=smooth)
    assert mu.dtype == np.float32 and mu.ndim == 3 and voxel == 1.0
    weights = physical.all_weights()
    world = physical.all_points()[0] @ POSE[:3, :3].T + POSE[:3, 3]
    # mu (1/mm) times the voxel volume (mm³) is an attenuation-weighted area (mm²), as the weights.
    total = mu.sum(dtype=np.float64) * voxel ** 3
    assert abs(total / weights.sum() - 1) < 1e-6
    z, y, x = (np.arange(n) for n in mu.shape)
    com = np.array([(mu.sum(axis=(0, 1), dtype=np.float64) * x).sum(),
                    (mu.sum(axis=(0, 2), dtype=np.float64) * y).sum(),
                    (mu.sum(axis=(1, 2), dtype=np.float64) * z).sum()]) / mu.sum(dtype=np.float64)
    np.testing.assert_allclose(origin + com * voxel, weights @ world / weights.sum(), atol=1e-3)
    # Every point lies inside the grid, 2 voxels + margin from its border.
    assert np.all(world.min(axis=0) - origin >= 2.0 + 2 * voxel - 1e-9)
    assert np.all(origin + (np.array(mu.shape[::-1]) - 1) * voxel - world.max(axis=0) >= 2.0 + 2 * voxel - 1e-9)


@pytest.mark.parametrize("tilt_deg", [0.0, 35.0])
def test_flat_sheet_projects_to_mu_t_over_cos_incidence(tilt_deg):
    view = View.from_gantry(-45, 0, shape=SHAPE, pixel_mm=PIXEL)
    step, half, mu_t = 0.25, 25.0, 0.8
    ax = np.arange(-half, half + step / 2, step)
    x, y = np.meshgrid(ax, ax)
    sheet = _model(np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)]), np.full(x.size, mu_t * step ** 2))
    T = pose_facing(view, focal_point_mm=(3.0, -2.0, 5.0)) @ make_transform(
        rotation_about_axis([1, 0, 0], np.deg2rad(tilt_deg)))
    image = rp.forward_project(rp.voxelise_model(sheet, T, voxel_mm=0.5), view, n_threads=THREADS)[0].ravel()

    rows, cols = np.mgrid[:SHAPE[0], :SHAPE[1]]
    rays = view.ray_directions(np.column_stack([cols.ravel(), rows.ravel()]))
    normal, centre = T[:3, 2], T[:3, 3]
    hit = view.source_mm + ((centre - view.source_mm) @ normal / (rays @ normal))[:, None] * rays
    local = (hit - centre) @ T[:3, :3]
    inner = np.all(np.abs(local[:, :2]) < half - 5.0, axis=1)
    expected = mu_t / np.abs(rays @ normal)
    assert inner.sum() > 300
    assert np.abs(image[inner] / expected[inner] - 1).max() < 0.02
    # Integrated over the detector (line integral x footprint at the sheet), the total attenuation.
    total = (image * view.pixel_footprint_mm2(hit)).sum()
    assert abs(total / (mu_t * step ** 2 * x.size) - 1) < 0.01
    assert np.all(image[np.all(np.abs(local[:, :2]) > half + 3.0, axis=1)] < 1e-6)


# --- frames ---------------------------------------------------------------------------------


class _Anatomy:
    def line_integrals(self, view):
        return np.full(view.shape, 0.7)


def test_render_frame_rtk_makes_a_consistent_hybrid_frame(coarse):
    digital, physical = coarse
    view = View.from_gantry(-45, 0, shape=SHAPE, pixel_mm=PIXEL, name="A")
    kwargs = dict(background=_Anatomy(), voxel_mm=1.0, n_threads=THREADS)
    frame = rp.render_frame_rtk(digital, physical, POSE, view, rng=np.random.default_rng(7), **kwargs)
    again = rp.render_frame_rtk(digital, physical, POSE, view, rng=np.random.default_rng(7), **kwargs)
    other = rp.render_frame_rtk(digital, physical, POSE, view, rng=np.random.default_rng(8), **kwargs)
    assert isinstance(frame, Frame) and frame.image.shape == SHAPE and frame.image.dtype == np.float32
    np.testing.assert_array_equal(frame.labels, render_labels(digital, POSE, view))
    np.testing.assert_array_equal(frame.T_carm_transducer, POSE)
    assert frame.meta == {"projector": "rtk-joseph", "voxel_mm": 1.0}
    np.testing.assert_array_equal(frame.image, again.image)
    assert not np.array_equal(frame.image, other.image)

    elements = frame.labels == Feature.TRANSDUCER
    background = frame.labels == Feature.BACKGROUND
    assert elements.sum() > 500 and background.sum() > 500
    # Elements: 1.4 /mm x 2 mm = 2.8 at normal incidence, on top of the 0.7 background.
    assert np.median(frame.image[elements]) > np.median(frame.image[background]) + 2.0
    assert abs(np.median(frame.image[background]) - 0.7) < 0.02

    clean = rp.render_frame_rtk(digital, physical, POSE, view, rng=np.random.default_rng(7), background=None,
                                photons_per_pixel=None, voxel_mm=1.0, n_threads=THREADS)
    assert np.percentile(clean.image[background], 90) < 0.01
    assert np.median(clean.image[elements]) > 2.5


# --- errors ---------------------------------------------------------------------------------


@pytest.mark.parametrize("voxel_mm, error", [(0.0, ValueError), (-0.5, ValueError), (float("nan"), ValueError),
                                             ("0.5", TypeError), (True, TypeError), (None, TypeError)])
def test_bad_voxel_mm_is_refused(coarse, voxel_mm, error):
    digital, physical = coarse
    with pytest.raises(error, match="voxel_mm"):
        rp.voxelise_model(physical, POSE, voxel_mm=voxel_mm)
    with pytest.raises(error, match="voxel_mm"):
        rp.render_frame_rtk(digital, physical, POSE, _views()[0], rng=np.random.default_rng(0), voxel_mm=voxel_mm)


def test_too_fine_a_grid_is_refused_before_allocating(coarse):
    with pytest.raises(ValueError, match="MAX_VOXELS"):
        rp.voxelise_model(coarse[1], POSE, voxel_mm=0.02)


def test_wrong_types_are_refused(coarse):
    digital, physical = coarse
    view = _views()[0]
    rng = np.random.default_rng(0)
    with pytest.raises(TypeError, match="model"):
        rp.voxelise_model("transducer", POSE)
    with pytest.raises(ValueError, match="T_carm_transducer"):
        rp.voxelise_model(physical, np.eye(3))
    with pytest.raises(ValueError, match="margin_mm"):
        rp.voxelise_model(physical, POSE, margin_mm=-1.0)
    with pytest.raises(ValueError, match="weight > 0"):
        rp.voxelise_model(_model(np.zeros((3, 3)), np.zeros(3), Feature.GAPS), POSE)
    with pytest.raises(TypeError, match="views"):
        rp.rtk_geometry([view, "B"])
    with pytest.raises(TypeError, match="views"):
        rp.forward_project(_ball((0, 0, 0)), [])
    with pytest.raises(TypeError, match="volume"):
        rp.forward_project(np.zeros((4, 4, 4), np.float32), view)
    with pytest.raises(ValueError, match="spacing_mm"):
        rp.forward_project((np.zeros((4, 4, 4), np.float32), np.zeros(3), -1.0), view)
    with pytest.raises(ValueError, match="mu_per_mm"):
        rp.forward_project((np.zeros((4, 4)), np.zeros(3), 1.0), view)
    with pytest.raises(ValueError, match="n_threads"):
        rp.forward_project(_ball((0, 0, 0)), view, n_threads=0)
    with pytest.raises(TypeError, match="digital"):
        rp.render_frame_rtk(None, physical, POSE, view, rng=rng)
    with pytest.raises(TypeError, match="physical"):
        rp.render_frame_rtk(digital, digital.points, POSE, view, rng=rng)
    with pytest.raises(TypeError, match="view"):
        rp.render_frame_rtk(digital, physical, POSE, [view], rng=rng)
    with pytest.raises(TypeError, match="rng"):
        rp.render_frame_rtk(digital, physical, POSE, view, rng=0)
    with pytest.raises(ValueError, match="photons_per_pixel"):
        rp.render_frame_rtk(digital, physical, POSE, view, rng=rng, photons_per_pixel=-5.0)
    with pytest.raises(ValueError, match="background"):
        rp.render_frame_rtk(digital, physical, POSE, view, rng=rng, background=np.zeros((3, 3)))


def test_skewed_intrinsics_are_refused():
    view = View.from_gantry(10, 5, shape=SHAPE, pixel_mm=PIXEL)
    K, R, source = view.decomposition
    K = K.copy()
    K[0, 1] = 0.05 * K[0, 0]
    skewed = View.from_matrix(K @ np.hstack([R, (-R @ source)[:, None]]), shape=SHAPE, pixel_mm=PIXEL, name="skew")
    with pytest.raises(ValueError, match="skew"):
        rp.rtk_geometry(skewed)


def test_missing_itk_rtk_raises_the_install_hint(monkeypatch, coarse):
    monkeypatch.setattr(rp, "_load", lambda: None)
    assert rp.rtk_available() is False
    view = _views()[0]
    calls = [
        lambda: rp.voxelise_model(coarse[1], POSE),
        lambda: rp.rtk_geometry(view),
        lambda: rp.forward_project(_ball((0, 0, 0)), view),
        lambda: rp.render_frame_rtk(*coarse, POSE, view, rng=np.random.default_rng(0)),
    ]
    for call in calls:
        with pytest.raises(ImportError, match=r"pip install 'histostudy\[rtk\]'"):
            call()
