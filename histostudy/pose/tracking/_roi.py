"""The region of a frame a warm-started tracking update looks at (§II-A eq. 1-2, §II-B.3):
:func:`region_of_interest` and the cropped, rescaled view :func:`crop_view`. Boxes are
``(row0, row1, col0, col1)``, half-open, in full-frame pixels; poses 4x4 ``T_carm_transducer`` (mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from histostudy.core import check_unit_fraction
from histostudy.imaging import View

__all__ = ["RegionOfInterest", "crop_view", "region_of_interest"]


@dataclass(frozen=True)
class RegionOfInterest:
    """A box of a view's detector and the view of its pixels at a label scale.

    Attributes:
        box: ``(row0, row1, col0, col1)`` half-open, full-frame pixels.
        scale: label pixels per frame pixel (1, 1/2, 1/4, ...).
        view: :func:`crop_view` of the box at ``scale``: its shape is the box's times ``scale``.
        frame_shape: the full detector's ``(rows, cols)``.
    """

    box: tuple
    scale: float
    view: View
    frame_shape: tuple

    @property
    def full_frame(self) -> bool:
        """True when the box is the whole detector."""
        return self.box == (0, self.frame_shape[0], 0, self.frame_shape[1])

    @property
    def area_fraction(self) -> float:
        """The box's share of the detector's pixels."""
        r0, r1, c0, c1 = self.box
        return (r1 - r0) * (c1 - c0) / float(self.frame_shape[0] * self.frame_shape[1])


def crop_view(view: View, box, scale: float = 1.0) -> View:
    """The view of ``box`` of ``view``'s detector resampled by ``scale`` (``P' = A P``, docs/tracking.md).

    ``box`` corners must be multiples of ``1 / scale`` frame pixels, so that the box holds whole
    label pixels. The pixel size grows to ``view.pixel_mm / scale``; the name is kept."""
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.View, got {type(view).__name__}")
    check_unit_fraction(scale)
    s = float(scale)
    r0, r1, c0, c1 = _check_box(box, view.shape)
    k = int(round(1.0 / s))
    if any(b % k for b in (r0, r1, c0, c1)):
        raise ValueError(f"box {tuple(box)!r} must have its corners on multiples of 1/scale = {k} frame pixels")
    offset = (s - 1.0) / 2.0
    A = np.array([[s, 0.0, -s * c0 + offset], [0.0, s, -s * r0 + offset], [0.0, 0.0, 1.0]])
    return View(P=A @ view.P, shape=((r1 - r0) // k, (c1 - c0) // k), pixel_mm=view.pixel_mm / s, name=view.name,
                gantry=None)


def _check_box(box, shape) -> tuple[int, int, int, int]:
    try:
        values = tuple(box)
        r0, r1, c0, c1 = (int(b) for b in values)
        if len(values) != 4 or any(int(b) != b for b in values):
            raise ValueError
    except (TypeError, ValueError):
        raise ValueError(f"box must be 4 integers (row0, row1, col0, col1) in frame pixels, got {box!r}") from None
    rows, cols = shape
    if not (0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols):
        raise ValueError(f"box {values!r} must lie in the detector's {tuple(shape)} pixels with row0 < row1 "
                         f"and col0 < col1")
    return r0, r1, c0, c1


def region_of_interest(view: View, points_mm, T_carm_transducer, *, margin_px: float, align_px: int,
                       scale: float = 1.0) -> RegionOfInterest:
    """The box where ``points_mm`` (transducer frame, mm) project at ``T_carm_transducer``, grown by
    ``margin_px`` frame pixels on each side, its corners moved outwards to multiples of ``align_px``
    and clipped to the detector; with its :func:`crop_view` at ``scale``.

    Points behind the source are ignored. When no point projects onto the detector the box is the
    whole detector (the caller then segments the frame as a whole). ``align_px`` must be a multiple
    of ``1 / scale`` (the U-Net's coarsest stride in frame pixels, ``UNetRunner.network_stride_px``,
    is), and the detector's rows and columns must be multiples of ``1 / scale``.
    """
    if not isinstance(view, View):
        raise TypeError(f"view must be a histostudy.imaging.View, got {type(view).__name__}")
    check_unit_fraction(scale)
    s = float(scale)
    k = int(round(1.0 / s))
    if isinstance(align_px, bool) or not isinstance(align_px, (int, np.integer)) or align_px < 1 or align_px % k:
        raise ValueError(f"align_px must be a positive integer multiple of 1/scale = {k}, got {align_px!r}")
    margin = float(margin_px) if not isinstance(margin_px, bool) else float("nan")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin_px must be a finite number >= 0 (frame pixels), got {margin_px!r}")
    rows, cols = view.shape
    if rows % k or cols % k:
        raise ValueError(f"view {view.name!r} shape {view.shape} is not divisible by 1/scale = {k}")
    T = np.asarray(T_carm_transducer, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_carm_transducer must be a finite 4x4 pose, got shape {T.shape}")
    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    uvw = view.project_homogeneous(pts @ T[:3, :3].T + T[:3, 3])
    front = uvw[:, 2] > 0
    uv = uvw[front, :2] / uvw[front, 2:3]
    on = view.in_image(uv) if len(uv) else np.zeros(0, bool)
    if not on.any():
        box = (0, rows, 0, cols)
    else:
        lo = np.floor(uv.min(axis=0) - margin)
        hi = np.ceil(uv.max(axis=0) + margin)
        # Outwards to the grid; the edge of the detector may end off-grid (the U-Net pads there).
        c0, r0 = (max(0, int(x // align_px * align_px)) for x in lo)
        c1, r1 = (int(-(-x // align_px) * align_px) for x in hi)
        c1, r1 = min(cols, c1), min(rows, r1)
        box = (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else (0, rows, 0, cols)
    return RegionOfInterest(box=tuple(int(b) for b in box), scale=s, view=crop_view(view, box, s),
                            frame_shape=(rows, cols))
