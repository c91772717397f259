"""Virtual x-ray projections of the transducer model (§II-B.2, eq. 1-2), the numpy reference: point
splatting into line integrals, the reference labels, quantum noise, and a complete synthetic frame
(docs/imaging.md, "Splatting")."""

from __future__ import annotations

import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from histostudy.core import stage
from histostudy.geometry import check_rigid
from histostudy.transducer import LABEL_PRIORITY, TransducerModel

from ..carm import View
from ..frame import Frame
from ._device import SEED_BOUND, check_device, mark_nearest_pixels_compiled, splat_compiled, splat_points, splat_torch
from ._memo import memoised_frames
from ._settings import check_n_splats, check_photons_per_pixel, check_splat_sigma_mm

__all__ = ["add_poisson_noise", "background_line_integrals", "render_frame", "render_labels",
           "render_line_integrals"]

#: Splat copies handled at once: bounds the working memory (~250 MB) whatever the model size.
_COPIES_PER_CHUNK = 1 << 22

#: Counts of 0 are replaced by this before the log (see :func:`add_poisson_noise`).
ZERO_COUNT_CLAMP = 0.5


# --- line integrals -------------------------------------------------------------------------


@stage("render")
def render_line_integrals(model: TransducerModel, T_carm_transducer, view: View, *,
                          rng: np.random.Generator, n_splats: int = 16,
                          splat_sigma_mm: float = 0.5, device=None) -> np.ndarray:
    """Line-integral image of the transducer by point splatting (§II-B.2).

    Each point with non-zero weight is copied ``n_splats`` times, each copy moved by an independent
    ``N(0, splat_sigma_mm²)`` offset per world axis and projected (eq. 1-2) to its nearest pixel,
    where it adds ``weight / (n_splats * footprint)`` (the footprint taken at the un-jittered point).
    Copies behind the source or off the detector add nothing. The draws depend only on the model,
    ``n_splats`` and ``rng``: the same seed gives a bit-identical image. Splat noise and the choice of
    the 0.125 mm model: docs/imaging.md, "Splatting".

    Args:
        model: the transducer model (the physical model, for synthetic frames).
        T_carm_transducer: (4, 4) rigid pose, transducer -> C-arm, mm.
        view: the C-arm view.
        rng: the Generator of the jitter.
        n_splats: copies per point, an integer >= 1.
        splat_sigma_mm: the jitter's standard deviation per axis, mm, >= 0 (0 projects each copy
            unmoved).
        device: None, this numpy reference; ``"cpu"``, the compiled kernel; ``"cuda"`` or
            ``"cuda:N"``, torch. The last two take one draw from ``rng`` as their jitter's seed, so
            their images match this one in distribution, not bits.

    Returns:
        ``(rows, cols)`` float32 image of line integrals.

    Raises:
        TypeError: ``model``, ``view`` or ``rng`` of the wrong type.
        ValueError: ``T_carm_transducer`` is not rigid, ``n_splats`` or ``splat_sigma_mm`` out of
            range, or ``device`` unknown or unavailable.
    """
    rows, cols = _check_view(view).shape
    device = check_device(device)
    if device is not None:
        return _render_on(device, model, T_carm_transducer, view, rng=rng, n_splats=n_splats,
                          splat_sigma_mm=splat_sigma_mm)
    image = np.zeros(rows * cols, dtype=np.float64)
    for flat, values in _splat_chunks(model, T_carm_transducer, view, rng=rng, n_splats=n_splats,
                                      splat_sigma_mm=splat_sigma_mm):
        image += np.bincount(flat, weights=values, minlength=rows * cols)
    return image.reshape(rows, cols).astype(np.float32)


def _render_on(device: str, model: TransducerModel, T_carm_transducer, view: View, *,
               rng: np.random.Generator, n_splats: int, splat_sigma_mm: float) -> np.ndarray:
    """:func:`render_line_integrals` on the compiled kernel (``"cpu"``) or torch (``"cuda…"``)."""
    _check_model(model, "model")
    T = check_rigid(T_carm_transducer, "T_carm_transducer")
    _check_rng(rng)
    n_splats = check_n_splats(n_splats)
    sigma = check_splat_sigma_mm(splat_sigma_mm)
    seed = int(rng.integers(SEED_BOUND))
    if device == "cpu":
        return splat_compiled(model, T, view, seed=seed, n_splats=n_splats, splat_sigma_mm=sigma)
    return splat_torch(model, T, view, device=device, seed=seed, n_splats=n_splats, splat_sigma_mm=sigma)


def _splat_chunks(model: TransducerModel, T_carm_transducer, view: View, *, rng: np.random.Generator,
                  n_splats: int, splat_sigma_mm: float) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield ``(flat pixel index int64, value float64)`` of the splat copies that hit the detector.

    The accumulation is left to the caller, so the benchmark can compare accumulators on exactly
    the same copies.
    """
    _check_model(model, "model")
    T = check_rigid(T_carm_transducer, "T_carm_transducer")
    _check_view(view)
    _check_rng(rng)
    n_splats = check_n_splats(n_splats)
    sigma = check_splat_sigma_mm(splat_sigma_mm)
    rows, cols = view.shape
    uvw, values = splat_points(model, T, view, n_splats)

    # float32 is ample for the jittered projection (u w ~ 1e6, relative error 1e-7 -> 1e-4 px).
    M = view.P[:, :3].astype(np.float32)
    base_all = uvw.T.astype(np.float32)
    chunk = max(1, _COPIES_PER_CHUNK // n_splats)
    for start in range(0, len(values), chunk):
        base = base_all[:, start:start + chunk]
        m = base.shape[1]
        if sigma > 0:
            # Component-major (3, copies) keeps each row contiguous: one fast GEMM, then row ops.
            offsets = rng.standard_normal((3, m * n_splats), dtype=np.float32)
            offsets *= np.float32(sigma)
            h = (M @ offsets).reshape(3, m, n_splats)
            h += base[:, :, None]
        else:
            h = np.broadcast_to(base[:, :, None], (3, m, n_splats))
        flat, ok = _nearest_pixel(h[0], h[1], h[2], rows, cols)
        yield flat, np.broadcast_to(values[start:start + chunk, None], ok.shape)[ok]


def _nearest_pixel(uw: np.ndarray, vw: np.ndarray, w: np.ndarray, rows: int,
                   cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat index of the pixel each homogeneous point falls in, and the mask of those on the detector.

    Pixel ``(r, c)`` covers ``[c - 0.5, c + 0.5) x [r - 0.5, r + 0.5)`` (carm's convention), so the
    index is ``floor(u + 0.5)``; after the bounds test the values are >= 0 and truncation is floor.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        col = uw / w
        col += 0.5
        row = vw / w
        row += 0.5
    ok = (w > 0) & (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    flat = row[ok].astype(np.int64) * cols + col[ok].astype(np.int64)
    return flat, ok


# --- labels ---------------------------------------------------------------------------------


@stage("render")
def render_labels(model: TransducerModel, T_carm_transducer, view: View, *, device=None) -> np.ndarray:
    """Reference label image of the transducer (§II-B.2): the values of :class:`~histostudy.transducer.Feature`.

    Each class's points are projected (eq. 1-2) without jitter to their nearest pixel; classes are
    painted from the lowest to the highest priority of :data:`~histostudy.transducer.LABEL_PRIORITY`,
    so a screw in front of an element is labelled SCREWS. Each class mask is closed (OpenCV, an
    elliptical kernel sized by the class's projected grid step) so that no pixel between its points
    stays empty, and pixels left empty on the seams between classes take the highest-priority class
    among their neighbours (docs/imaging.md, "Label holes").

    Args:
        model: the transducer model (the digital model, for the reference labels).
        T_carm_transducer: (4, 4) rigid pose, transducer -> C-arm, mm.
        view: the C-arm view.
        device: None projects in numpy; any other device of :func:`render_frame` projects with the
            compiled kernel (the same float64 arithmetic in another order: a point within rounding of
            a pixel edge may fall on its other side).

    Returns:
        ``(rows, cols)`` uint8 label image.

    Raises:
        TypeError: ``model`` or ``view`` of the wrong type.
        ValueError: ``T_carm_transducer`` is not rigid, or ``device`` is unknown or unavailable.
    """
    _check_model(model, "model")
    T = check_rigid(T_carm_transducer, "T_carm_transducer")
    rows, cols = _check_view(view).shape
    marker = _numpy_marker if check_device(device) is None else mark_nearest_pixels_compiled
    labels = np.zeros((rows, cols), dtype=np.uint8)
    largest_step_px = 0.0
    grid_step_mm = model.grid_step_mm
    assert grid_step_mm is not None
    for feature in reversed(LABEL_PRIORITY):
        pts = model.points[feature]
        if len(pts) == 0:
            continue
        mask, smallest_footprint = marker(pts, T, view)
        if not np.isfinite(smallest_footprint):
            continue
        step_px = grid_step_mm[feature] / math.sqrt(smallest_footprint)
        largest_step_px = max(largest_step_px, step_px)
        labels[_close_holes(mask.reshape(rows, cols), step_px) > 0] = int(feature)
    return _fill_seams(labels, largest_step_px)


def _numpy_marker(points: np.ndarray, T: np.ndarray, view: View) -> tuple[np.ndarray, float]:
    """The flat uint8 mask of the pixels ``points`` land in, and their smallest footprint (inf: none)."""
    rows, cols = view.shape
    world = points @ T[:3, :3].T + T[:3, 3]
    uvw = view.project_homogeneous(world)
    flat, ok = _nearest_pixel(uvw[:, 0], uvw[:, 1], uvw[:, 2], rows, cols)
    mask = np.zeros(rows * cols, dtype=np.uint8)
    if flat.size == 0:
        return mask, math.inf
    mask[flat] = 1
    return mask, float(view.pixel_footprint_mm2(world[ok]).min())


def _fill_seams(labels: np.ndarray, step_px: float) -> np.ndarray:
    """Give pixels left empty between two classes' regions the higher-priority neighbour.

    Closing each class alone cannot fill a pixel on the seam between two classes (it lies outside
    both); closing their union finds those pixels, and a dilation of the priority ranks labels them.
    """
    kernel = _closing_kernel(step_px)
    if kernel is None:
        return labels
    foreground = (labels > 0).astype(np.uint8)
    seams = (cv2.morphologyEx(foreground, cv2.MORPH_CLOSE, kernel) > 0) & (foreground == 0)
    if not seams.any():
        return labels
    rank = _RANK_OF_LABEL[labels]
    neighbour = cv2.dilate(rank, kernel)
    labels = labels.copy()
    labels[seams] = _LABEL_OF_RANK[neighbour[seams]]
    return labels


def _closing_kernel(step_px: float) -> np.ndarray | None:
    """Elliptical kernel that closes the holes a grid of projected step ``step_px`` can leave, or None."""
    widest_hole = math.ceil(math.sqrt(2.0) * step_px) - 1
    if widest_hole < 1:
        return None
    radius = math.ceil(widest_hole / 2)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _close_holes(mask: np.ndarray, step_px: float) -> np.ndarray:
    kernel = _closing_kernel(step_px)
    return mask if kernel is None else cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)


# Label value <-> overlap rank (0 background, len(LABEL_PRIORITY) the highest priority).
_RANK_OF_LABEL = np.zeros(256, dtype=np.uint8)
_LABEL_OF_RANK = np.zeros(256, dtype=np.uint8)
for _rank, _feature in enumerate(reversed(LABEL_PRIORITY), start=1):
    _RANK_OF_LABEL[int(_feature)] = _rank
    _LABEL_OF_RANK[_rank] = int(_feature)


# --- noise ----------------------------------------------------------------------------------


def add_poisson_noise(line_integrals, photons_per_pixel: float, rng: np.random.Generator) -> np.ndarray:
    """Quantum noise on a line-integral image (§II-B.2): ``counts ~ Poisson(N0 exp(-p))``.

    A pixel with 0 counts has no finite log; it is set to ``ZERO_COUNT_CLAMP`` = 0.5 counts, the
    midpoint between the observable 0 and 1, which caps the image at ``log(2 N0)`` (11.5 at
    N0 = 5e4) and biases those pixels less than clamping to 1 would.

    Args:
        line_integrals: image ``p`` of line integrals (dimensionless, any shape), finite.
        photons_per_pixel: ``N0``, the unattenuated photons per pixel, finite and > 0.
        rng: the Generator the counts are drawn from.

    Returns:
        ``-log(counts / N0)`` as float32, of ``line_integrals``' shape.

    Raises:
        ValueError: ``line_integrals`` is not finite, or ``photons_per_pixel`` is out of range.
        TypeError: ``rng`` is not a ``numpy.random.Generator``.
    """
    p = np.asarray(line_integrals, dtype=np.float64)
    if not np.all(np.isfinite(p)):
        raise ValueError("line_integrals must be finite; found NaN or inf")
    n0 = check_photons_per_pixel(photons_per_pixel, allow_none=False)
    _check_rng(rng)
    counts = rng.poisson(n0 * np.exp(-p)).astype(np.float64)
    np.maximum(counts, ZERO_COUNT_CLAMP, out=counts)
    return (-np.log(counts / n0)).astype(np.float32)


# --- frames ---------------------------------------------------------------------------------


# outside the memo: a frame handed out again is a render call, charged its look-up and copy
@stage("render")
@memoised_frames  # inside shared_frames(), a frame rendered before is handed out again
def render_frame(model: TransducerModel, T_carm_transducer, view: View, *, rng: np.random.Generator,
                 physical: TransducerModel | None = None, background=None,
                 photons_per_pixel: float | None = 5e4, n_splats: int = 16, splat_sigma_mm: float = 0.5,
                 labels_from: str = "digital", device=None) -> Frame:
    """A synthetic fluoroscopic frame: hybrid image, reference labels and the true pose (§II-B.2).

    Args:
        model: the digital model; its labels are the reference (the paper annotated its
            evaluation images with the digital model aligned by hand).
        T_carm_transducer: true 4x4 pose, transducer -> C-arm frame.
        view: the projection geometry.
        rng: the Generator for the splat jitter, then the noise.
        physical: the transducer that makes the image (:meth:`TransducerModel.build_physical`);
            default ``model``. Use a 0.125 mm model here for paper-like images (see the splat
            noise note of :func:`render_line_integrals`); labels may come from a coarser ``model``.
        background: line integrals under the transducer: None (zeros), a ``(rows, cols)`` array
            (e.g. a real projection, giving the paper's hybrid images), or any object with a
            method ``line_integrals(view) -> (rows, cols) array`` (a procedural anatomy).
        photons_per_pixel: unattenuated photons per pixel for Poisson noise; None for none.
        n_splats, splat_sigma_mm: splatting parameters (paper: 16 and 0.5 mm).
        labels_from: ``"digital"`` (labels from ``model``) or ``"physical"`` (from the model that
            made the image: ``physical`` if given, else ``model``).
        device: where the splatting runs (:func:`render_line_integrals`): None, the numpy
            reference (the study's renders); ``"cpu"``, compiled; ``"cuda"``, torch.
    """
    _check_model(model, "model")
    if physical is not None:
        _check_model(physical, "physical")
    if labels_from not in ("digital", "physical"):
        raise ValueError(f"labels_from must be 'digital' or 'physical', got {labels_from!r}")
    T = check_rigid(T_carm_transducer, "T_carm_transducer")
    _check_view(view)
    _check_rng(rng)
    device = check_device(device)
    imaging = model if physical is None else physical
    if device is None:
        back = background_line_integrals(background, view)
        splat = render_line_integrals(imaging, T, view, rng=rng, n_splats=n_splats, splat_sigma_mm=splat_sigma_mm)
    else:
        # The compiled and CUDA splats run without the GIL: the scene's line integrals (numpy, one
        # thread) fill a core meanwhile. Nothing random is drawn there, so the frame is the same.
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = pool.submit(background_line_integrals, background, view)
            splat = render_line_integrals(imaging, T, view, rng=rng, n_splats=n_splats,
                                          splat_sigma_mm=splat_sigma_mm, device=device)
            back = pending.result()
    image = back + splat.astype(np.float64)
    if photons_per_pixel is not None:
        image = add_poisson_noise(image, photons_per_pixel, rng)
    labels = render_labels(model if labels_from == "digital" else imaging, T, view, device=device)
    meta = {
        "renderer": "point splatting (§II-B.2)",
        "splat_device": "numpy" if device is None else str(device),
        "n_splats": int(n_splats),
        "splat_sigma_mm": float(splat_sigma_mm),
        "photons_per_pixel": None if photons_per_pixel is None else float(photons_per_pixel),
        "model_spacing_mm": model.spacing_mm,
        "physical": physical is not None,
        "physical_spacing_mm": None if physical is None else physical.spacing_mm,
        "focal_point_mm": imaging.focal_point_mm.tolist(),
        "labels_from": labels_from,
        "background": _describe(background),
    }
    return Frame(image=image.astype(np.float32), view=view, labels=labels, T_carm_transducer=T, meta=meta)


def background_line_integrals(background, view: View) -> np.ndarray:
    """The line integrals of a frame's background, checked.

    Args:
        background: None (zeros), a ``view.shape`` array of line integrals, or an object with
            ``line_integrals(view)`` (an :class:`~histostudy.imaging.anatomy.Anatomy` scene).
        view: the C-arm view whose detector the background covers.

    Returns:
        ``view.shape`` float64 array (rows, cols).

    Raises:
        TypeError: ``background`` is none of the three.
        ValueError: its shape is not ``view.shape`` or it is not finite.
    """
    if background is None:
        return np.zeros(view.shape)
    source = background
    if not isinstance(background, np.ndarray) and callable(getattr(background, "line_integrals", None)):
        source = background.line_integrals(view)
    try:
        arr = np.asarray(source, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"background must be None, a {view.shape} array of line integrals, or an object with "
            f"line_integrals(view); got {type(background).__name__}"
        ) from None
    if arr.shape != view.shape:
        raise ValueError(f"background must have the view's shape {view.shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("background must be finite line integrals; found NaN or inf")
    return arr


def _describe(background) -> str:
    if background is None:
        return "none"
    if isinstance(background, np.ndarray):
        return "array"
    return type(background).__name__


# --- validation -----------------------------------------------------------------------------


def _check_model(model, name: str) -> TransducerModel:
    if not isinstance(model, TransducerModel):
        raise TypeError(f"{name} must be a histostudy.transducer.TransducerModel, got {type(model).__name__}")
    return model


def _check_view(view) -> View:
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.carm.View, got {type(view).__name__}")
    return view


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng
