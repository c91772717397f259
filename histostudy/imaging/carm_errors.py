"""How a lab's C-arm geometry departs from its calibration (eq. 1): a miscalibrated source and principal
point, and a gantry that sags rigidly; each returns a new view (world mm, pixels). See docs/imaging.md."""

from __future__ import annotations

import numpy as np

from histostudy.geometry import invert_transform

from .carm import View

__all__ = ["GRAVITY_CARM", "displaced_view", "miscalibrated_view"]

#: Gravity in the C-arm frame (LPS, patient supine: posterior = down).
GRAVITY_CARM = np.array([0.0, 1.0, 0.0])


def _vector(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be {n} finite numbers, got {value!r}")
    return arr


def miscalibrated_view(view: View, *, source_offset_mm=(0.0, 0.0, 0.0), detector_shift_px=(0.0, 0.0)) -> View:
    """The geometry of a C-arm whose calibration says ``view`` while its source sits
    ``source_offset_mm`` (world mm) away, its detector unmoved, and its principal point is
    ``detector_shift_px`` (u, v) off.

    With ``P = K R [I | -C]``, moving the source by ``d`` (``d_cam = R d``) with the detector plane
    fixed changes the distance to the detector from ``f`` to ``f - d_z`` and moves the principal
    point (the source's foot on the detector) by ``(d_x, d_y)``: every point of the detector
    plane keeps its pixel, and points off it move with their distance from it. Zero offsets
    return the same matrix.
    """
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.View, got {type(view).__name__}")
    d_world = _vector(source_offset_mm, 3, "source_offset_mm")
    shift = _vector(detector_shift_px, 2, "detector_shift_px")
    K, R, source = view.decomposition
    d_cam = R @ d_world
    focal_mm = K[0, 0] * view.pixel_mm  # source-detector distance along the principal ray
    if not abs(d_cam[2]) < 0.5 * focal_mm:
        raise ValueError(f"source_offset_mm {d_world.tolist()} moves the source by more than half its distance to the "
                         f"detector ({focal_mm:.0f} mm): expected a calibration error of a few mm")
    scale = (focal_mm - d_cam[2]) / focal_mm
    K_new = K.copy()
    K_new[:2, :2] *= scale
    K_new[0, 2] += d_cam[0] * K[0, 0] / focal_mm + shift[0]
    K_new[1, 2] += d_cam[1] * K[1, 1] / focal_mm + shift[1]
    new_source = source + d_world
    return View.from_krt(K_new, R, -R @ new_source, view.shape, view.pixel_mm, name=view.name)


def displaced_view(view: View, T_world_motion) -> View:
    """The view of the same C-arm after its source and detector moved rigidly by ``T_world_motion``
    (4x4, world mm): a point ``x`` is seen as the calibrated geometry sees ``T^-1 x``."""
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.View, got {type(view).__name__}")
    T = np.asarray(T_world_motion, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_world_motion must be a finite 4x4 rigid transform, got shape {T.shape}")
    P = view.P @ invert_transform(T)
    return View(P=P, shape=view.shape, pixel_mm=view.pixel_mm, name=view.name)
