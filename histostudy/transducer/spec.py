"""The transducer's specification (§II-B.1): geometry and attenuation, the feature classes, the label
priority where classes overlap (§II-B.2) and the quadrants. Transducer frame: origin at the geometric
focal point, +z towards the transducer (depth is -z, TB is y, LR is x); mm, 1/mm."""

from __future__ import annotations

import enum
import json
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from histostudy.core import atomic_write_json

__all__ = [
    "FEATURE_CLASSES",
    "LABEL_PRIORITY",
    "Feature",
    "TransducerSpec",
    "check_label_image",
    "quadrant_index",
]

SPEC_FORMAT = "histostudy.transducer_spec"
SPEC_FORMAT_VERSION = 1


class Feature(enum.IntEnum):
    """Point / pixel classes of §II-B.1-2; the values are the label-image values."""

    BACKGROUND = 0
    TRANSDUCER = 1  # main transducer elements
    OUTER_BOUNDARY = 2
    INNER_BOUNDARY = 3
    GAPS = 4
    SCREWS = 5


def check_label_image(labels, shape: tuple[int, int] | None = None, name: str = "labels") -> np.ndarray:
    """A label image checked to hold :class:`Feature` values (0..5).

    Args:
        labels: ``(rows, cols)`` array: integers, booleans, or floats holding whole numbers.
        shape: the ``(rows, cols)`` it must have (the image's), or None.
        name: what the error message calls ``labels``.

    Returns:
        ``(rows, cols)`` uint8 label image.

    Raises:
        ValueError: not 2-D or not ``shape``; another dtype; or a value outside 0..5 (which a plain
            ``astype(uint8)`` would wrap silently: 300 -> 44, -1 -> 255), named with the offending
            values.
    """
    arr = np.asarray(labels)
    if arr.ndim != 2 or (shape is not None and arr.shape != tuple(shape)):
        expected = "a 2-D (rows, cols) array" if shape is None else f"shape {tuple(shape)} (the image's)"
        raise ValueError(f"{name} must be {expected}, got shape {arr.shape}")
    if arr.dtype == np.uint8:
        bad = arr > max(Feature)
    elif arr.dtype == bool or np.issubdtype(arr.dtype, np.integer):
        bad = (arr < 0) | (arr > max(Feature))
    elif np.issubdtype(arr.dtype, np.floating):
        bad = ~np.isfinite(arr) | (arr != np.round(arr)) | (arr < 0) | (arr > max(Feature))
    else:
        raise ValueError(f"{name} must hold Feature values 0..{int(max(Feature))}, got dtype {arr.dtype}")
    if bad.any():
        values = np.unique(arr[bad])[:5].tolist()
        raise ValueError(f"{name} must hold Feature values 0..{int(max(Feature))} (integers), got {values} "
                         f"in {int(bad.sum())} pixels")
    return arr.astype(np.uint8, copy=False)


#: The five point classes of the model, in enum order.
FEATURE_CLASSES: tuple[Feature, ...] = (
    Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS, Feature.SCREWS,
)

#: Overlap order of §II-B.2, highest first: a pixel covered by several classes gets the first one.
LABEL_PRIORITY: tuple[Feature, ...] = (
    Feature.SCREWS, Feature.GAPS, Feature.INNER_BOUNDARY, Feature.OUTER_BOUNDARY, Feature.TRANSDUCER,
)


@dataclass(frozen=True)
class TransducerSpec:
    """Geometry and x-ray attenuation of the transducer (§II-B.1, §II-D); defaults are the paper's.

    The four quadrants, fabricated separately, are split along the x = 0 and y = 0 planes. Fields
    marked "assumed" are not in the paper; each is a field so that a user can replace it. Lengths in
    mm, attenuation in 1/mm at ~70 keV.

    Args:
        radius_mm: radius of the spherical cap, 138.7 mm; its centre is the geometric focal point.
        aperture_x_mm: full width of the elliptical active aperture along x (LR), in plan view
            (paper: "approximately 24 x 17 cm").
        aperture_y_mm: the same along y (TB).
        cutout_diameter_mm: central circular cutout for the imaging probe, 6.4 cm.
        gap_width_mm: assumed 1.5, width of the gap between quadrants (the GAPS stripes
            ``|x|, |y| < w/2``).
        outer_band_mm: assumed 3.0, width in plan view of the boundary band at the elliptical edge
            (its inner edge is the ellipse of half-axes a - w, b - w, within 0.1 mm of a true offset
            curve here).
        inner_band_mm: assumed 3.0, the same at the cutout edge.
        element_thickness_mm: assumed 2.0, the elements as one PZT shell.
        element_mu_per_mm: assumed 1.4, its effective attenuation (lead-based ceramic: about
            1.2-1.7 /mm).
        rim_thickness_mm: assumed 2.0, the housing rim at both edges: a flange under the boundary band
            (the band carries element + flange) and a cylindrical wall rising in +z from the cap edge,
            so the boundaries show as lines when seen edge-on.
        rim_mu_per_mm: assumed 0.2, between aluminium (~0.06) and brass (~1).
        outer_wall_height_mm: assumed 8.0, height of the outer wall along +z.
        inner_wall_height_mm: assumed 8.0, height of the inner wall along +z.
        screw_count: assumed 8, steel screws in the middle of the outer band, axis along +z from the
            cap surface into the rim, at ellipse parameter angles (k + 1/2) 360/n deg (so none falls
            in a gap); an integer >= 0.
        screw_diameter_mm: assumed 3.0.
        screw_length_mm: assumed 8.0.
        screw_mu_per_mm: assumed 0.4 (steel: effective 0.3-0.5 /mm).

    Raises:
        TypeError: a field is not a number.
        ValueError: a field not finite or out of range, or a geometry that does not fit (see the
            messages).
    """

    radius_mm: float = 138.7
    aperture_x_mm: float = 240.0
    aperture_y_mm: float = 170.0
    cutout_diameter_mm: float = 64.0
    gap_width_mm: float = 1.5
    outer_band_mm: float = 3.0
    inner_band_mm: float = 3.0
    element_thickness_mm: float = 2.0
    element_mu_per_mm: float = 1.4
    rim_thickness_mm: float = 2.0
    rim_mu_per_mm: float = 0.2
    outer_wall_height_mm: float = 8.0
    inner_wall_height_mm: float = 8.0
    screw_count: int = 8
    screw_diameter_mm: float = 3.0
    screw_length_mm: float = 8.0
    screw_mu_per_mm: float = 0.4

    def __post_init__(self):
        positive = ("radius_mm", "aperture_x_mm", "aperture_y_mm", "cutout_diameter_mm", "outer_band_mm",
                    "inner_band_mm", "element_thickness_mm", "rim_thickness_mm", "screw_diameter_mm",
                    "screw_length_mm")
        non_negative = ("gap_width_mm", "element_mu_per_mm", "rim_mu_per_mm", "outer_wall_height_mm",
                        "inner_wall_height_mm", "screw_mu_per_mm")
        for name in positive + non_negative:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise TypeError(f"{name} must be a number in the unit its name gives, got {value!r}")
            value = float(value)
            object.__setattr__(self, name, value)
            if not math.isfinite(value) or value < 0 or (name in positive and value == 0):
                expected = "> 0" if name in positive else ">= 0"
                raise ValueError(f"{name} must be finite and {expected}, got {value!r}")
        count = self.screw_count
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
            raise ValueError(f"screw_count must be an integer >= 0, got {count!r}")
        object.__setattr__(self, "screw_count", int(count))
        self._check_proportions()

    def _check_proportions(self) -> None:
        a, b, R = self.aperture_x_mm / 2, self.aperture_y_mm / 2, self.radius_mm
        if max(a, b) >= R:
            raise ValueError(
                f"aperture half-widths ({a:g}, {b:g}) mm must be smaller than radius_mm {R:g}: "
                f"the aperture must lie on the spherical cap"
            )
        if self.cutout_diameter_mm >= min(self.aperture_x_mm, self.aperture_y_mm):
            raise ValueError(
                f"cutout_diameter_mm {self.cutout_diameter_mm:g} must be smaller than the aperture's "
                f"narrowest width min({self.aperture_x_mm:g}, {self.aperture_y_mm:g}) mm"
            )
        inner_edge = self.cutout_diameter_mm / 2 + self.inner_band_mm
        outer_edge = min(a, b) - self.outer_band_mm
        if inner_edge >= outer_edge:
            raise ValueError(
                f"inner_band_mm {self.inner_band_mm:g} and outer_band_mm {self.outer_band_mm:g} leave no "
                f"element between the cutout (radius {self.cutout_diameter_mm / 2:g} mm) and the "
                f"aperture edge (half-width {min(a, b):g} mm)"
            )
        if self.gap_width_mm >= self.cutout_diameter_mm:
            raise ValueError(
                f"gap_width_mm {self.gap_width_mm:g} must be smaller than cutout_diameter_mm "
                f"{self.cutout_diameter_mm:g}"
            )
        if self.screw_diameter_mm > self.outer_band_mm + self.rim_thickness_mm:
            raise ValueError(
                f"screw_diameter_mm {self.screw_diameter_mm:g} must fit the rim: at most outer_band_mm + "
                f"rim_thickness_mm = {self.outer_band_mm + self.rim_thickness_mm:g} mm"
            )

    # --- serialisation ------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """Plain-JSON form: ``{field: value}``."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TransducerSpec:
        """A spec from :meth:`to_dict`'s form; missing fields take the paper defaults."""
        if not isinstance(data, dict):
            raise TypeError(f"data must be a dict of TransducerSpec fields, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"data has unknown TransducerSpec fields {unknown}; expected a subset of {sorted(known)}")
        return cls(**data)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the spec as JSON (atomically): ``{"format", "version", "spec": {...}}``."""
        return atomic_write_json(path, {"format": SPEC_FORMAT, "version": SPEC_FORMAT_VERSION, "spec": self.to_dict()})

    @classmethod
    def load(cls, path: str | os.PathLike) -> TransducerSpec:
        """Read a spec written by :meth:`save`, or a bare JSON object of fields."""
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        if isinstance(data, dict) and "format" in data:
            if data["format"] != SPEC_FORMAT:
                raise ValueError(f"{path}: expected format {SPEC_FORMAT!r}, got {data['format']!r}")
            data = data.get("spec")
        return cls.from_dict(data)



def quadrant_index(points_mm) -> np.ndarray:
    """Quadrant of each point (transducer frame): 0 (+x,+y), 1 (-x,+y), 2 (-x,-y), 3 (+x,-y).

    Points on a split plane (x = 0 or y = 0, inside the gaps) go to the + side.
    """
    p = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    right, top = p[:, 0] >= 0, p[:, 1] >= 0
    return np.where(top, np.where(right, 0, 1), np.where(right, 3, 2)).astype(np.intp)
