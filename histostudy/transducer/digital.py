"""The histotripsy transducer: its specification and point-cloud models (paper §II-B.1).

Transducer frame (docs/architecture.md, Frames and units): origin at the geometric focal point,
i.e. the centre of the spherical cap; +z from the focal point towards the transducer centre, so
the cap apex is at ``(0, 0, R)``. The paper's "depth" is -z, TB is y and LR is x. Lengths in mm,
angles in rad (``*_deg`` at edges).

A :class:`TransducerModel` is a point cloud, one array per :class:`Feature` class, on a regular grid
(paper: 0.47 mm for pose estimation, 0.125 mm for rendering). Each point carries an
*attenuation-weighted area* in mm² — the linear attenuation coefficient times the material
thickness times the area the point stands for (``mu * volume`` for volumetric points) — so that
the line integral a ray sees is ``sum(weight) / pixel_footprint_mm2`` (see
:meth:`histostudy.imaging.carm.View.pixel_footprint_mm2`). GAPS points mark the absence of material and
weigh exactly 0.

:meth:`TransducerModel.build` makes the digital model the pose estimation uses;
:meth:`TransducerModel.build_physical` makes the "physical" transducer that differs from it as
the real one did (§IV): quadrants slightly off their nominal place, and screws outside the CBCT
field of view the digital model was made from. :func:`pose_facing` gives the paper's set-up pose.
"""

from __future__ import annotations

import enum
import json
import math
import os
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from histostudy.core import atomic_write_json
from histostudy.geometry import make_transform, matrix_from_rotvec, rotation_about_axis

__all__ = [
    "FEATURE_CLASSES",
    "LABEL_PRIORITY",
    "Feature",
    "ManufacturingDeviation",
    "TransducerModel",
    "TransducerSpec",
    "pose_facing",
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


#: The five point classes of the model, in enum order.
FEATURE_CLASSES: tuple[Feature, ...] = (
    Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS, Feature.SCREWS,
)

#: Overlap order of §II-B.2, highest first: a pixel covered by several classes gets the first one.
LABEL_PRIORITY: tuple[Feature, ...] = (
    Feature.SCREWS, Feature.GAPS, Feature.INNER_BOUNDARY, Feature.OUTER_BOUNDARY, Feature.TRANSDUCER,
)


# --- specification --------------------------------------------------------------------------


@dataclass(frozen=True)
class TransducerSpec:
    """Geometry and x-ray attenuation of the transducer; defaults are the paper's transducer.

    From the paper (§II-B.1, §II-D):
        radius_mm: radius of the spherical cap, 138.7 mm; its centre is the geometric focal point.
        aperture_x_mm, aperture_y_mm: full widths of the elliptical active aperture along x (LR)
            and y (TB), "approximately 24 x 17 cm"; measured in the x-y plane (plan view).
        cutout_diameter_mm: central circular cutout for the imaging probe, 6.4 cm.
        The four quadrants, fabricated separately, are split along the x = 0 and y = 0 planes.

    Assumptions (not in the paper; each a field so a user can replace it):
        gap_width_mm = 1.5: width of the gap between quadrants (the GAPS stripes |x|, |y| < w/2).
        outer_band_mm = 3.0, inner_band_mm = 3.0: width, in plan view, of the boundary bands at the
            elliptical edge and at the cutout edge. (The outer band's inner edge is the ellipse of
            half-axes a - w, b - w, which is within 0.1 mm of a true offset curve here.)
        element_thickness_mm = 2.0, element_mu_per_mm = 1.4: the elements as one PZT shell of
            effective attenuation at ~70 keV (lead-based ceramic: about 1.2-1.7 /mm).
        rim_thickness_mm = 2.0, rim_mu_per_mm = 0.2: the housing rim at both edges — a flange
            under the boundary band (the band carries element + flange) and a cylindrical wall
            rising in +z from the cap edge, so the boundaries show as lines when seen edge-on.
            0.2 /mm is an effective value between aluminium (~0.06) and brass (~1) at ~70 keV.
        outer_wall_height_mm = 8.0, inner_wall_height_mm = 8.0: height of those walls along +z.
        screw_count = 8, screw_diameter_mm = 3.0, screw_length_mm = 8.0, screw_mu_per_mm = 0.4:
            steel screws (effective mu 0.3-0.5 /mm) in the middle of the outer band, axis along
            +z from the cap surface into the rim, at ellipse parameter angles (k + 1/2) 360/n deg
            (so none falls in a gap).
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
    def from_dict(cls, data: dict) -> "TransducerSpec":
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
    def load(cls, path: str | os.PathLike) -> "TransducerSpec":
        """Read a spec written by :meth:`save`, or a bare JSON object of fields."""
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        if isinstance(data, dict) and "format" in data:
            if data["format"] != SPEC_FORMAT:
                raise ValueError(f"{path}: expected format {SPEC_FORMAT!r}, got {data['format']!r}")
            data = data.get("spec")
        return cls.from_dict(data)


@dataclass(frozen=True)
class ManufacturingDeviation:
    """How the physical transducer differs from its digital model (§IV; all values assumptions).

    Attributes:
        quadrant_offset_sd_mm: SD of each quadrant's rigid offset, per axis (0.2 mm).
        quadrant_tilt_sd_deg: SD of each quadrant's small rotation about its own centroid, per
            rotation-vector component (0.15 deg). Such a tilt also moves the quadrant's sphere
            centre (by about R x angle), hence the acoustic focal point.
        extra_screw_count: screws on the probe mount behind the cutout that the digital model lacks
            (the paper's screws "further away from the transducer", outside the CBCT field of view).
        extra_screw_ring_radius_mm: their distance from the transducer axis.
        extra_screw_height_mm: height of their base above the cap apex (z = R + this).
    Zeros make the quadrants identical to the digital model.
    """

    quadrant_offset_sd_mm: float = 0.2
    quadrant_tilt_sd_deg: float = 0.15
    extra_screw_count: int = 4
    extra_screw_ring_radius_mm: float = 40.0
    extra_screw_height_mm: float = 30.0

    def __post_init__(self):
        for name in ("quadrant_offset_sd_mm", "quadrant_tilt_sd_deg", "extra_screw_ring_radius_mm",
                     "extra_screw_height_mm"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise TypeError(f"{name} must be a number, got {value!r}")
            if not math.isfinite(float(value)) or float(value) < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
            object.__setattr__(self, name, float(value))
        count = self.extra_screw_count
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
            raise ValueError(f"extra_screw_count must be an integer >= 0, got {count!r}")
        object.__setattr__(self, "extra_screw_count", int(count))

    def to_dict(self) -> dict:
        return asdict(self)


# --- model ----------------------------------------------------------------------------------


@dataclass(eq=False)
class TransducerModel:
    """A point-cloud transducer in the transducer frame (§II-B.1).

    Attributes:
        spec: the :class:`TransducerSpec` it was built from.
        spacing_mm: grid spacing of the points.
        points: ``{Feature: (n, 3) float64}`` in mm, one entry per :data:`FEATURE_CLASSES` member.
        weights: ``{Feature: (n,) float64}`` attenuation-weighted area of each point in mm²
            (``mu * thickness * area`` for surfaces, ``mu * volume`` for screws, 0 for GAPS).
        focal_point_mm: ``(3,)`` acoustic focal point in the transducer frame; zeros for the
            digital model, the mean of the quadrants' perturbed sphere centres for a physical one.
        deviation: the :class:`ManufacturingDeviation` of a physical model, None for the digital.
        quadrant_transforms: ``(4, 4, 4)`` rigid transforms, nominal -> physical position of the
            quadrants (order of :func:`quadrant_index`), None for the digital model.
        grid_step_mm: ``{Feature: float}`` largest 3-D distance between neighbouring grid points of
            the class (the cap grid is regular in x-y, so it stretches by R/z on the surface);
            the label renderer sizes its hole closing from it. Default: ``spacing_mm``.
    """

    spec: TransducerSpec
    spacing_mm: float
    points: dict
    weights: dict
    focal_point_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    deviation: ManufacturingDeviation | None = None
    quadrant_transforms: np.ndarray | None = None
    grid_step_mm: dict | None = None

    def __post_init__(self):
        if not isinstance(self.spec, TransducerSpec):
            raise TypeError(f"spec must be a TransducerSpec, got {type(self.spec).__name__}")
        self.spacing_mm = _check_spacing(self.spacing_mm)
        points, weights = {}, {}
        for feature in FEATURE_CLASSES:
            if feature not in self.points or feature not in self.weights:
                raise ValueError(f"points and weights need an entry for {feature.name} (possibly empty)")
            p = np.asarray(self.points[feature], dtype=np.float64).reshape(-1, 3)
            w = np.asarray(self.weights[feature], dtype=np.float64).reshape(-1)
            if len(p) != len(w):
                raise ValueError(f"{feature.name}: {len(p)} points but {len(w)} weights")
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(w)) and np.all(w >= 0)):
                raise ValueError(f"{feature.name}: points must be finite and weights finite and >= 0")
            points[feature], weights[feature] = p, w
        self.points, self.weights = points, weights
        fp = np.asarray(self.focal_point_mm, dtype=np.float64).reshape(-1)
        if fp.shape != (3,) or not np.all(np.isfinite(fp)):
            raise ValueError(f"focal_point_mm must be 3 finite numbers (mm), got {self.focal_point_mm!r}")
        self.focal_point_mm = fp
        steps = dict(self.grid_step_mm or {})
        self.grid_step_mm = {f: float(steps.get(f, self.spacing_mm)) for f in FEATURE_CLASSES}

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def build(cls, spec: TransducerSpec | None = None, spacing_mm: float = 0.47) -> "TransducerModel":
        """The digital model (§II-B.1) on a regular grid of ``spacing_mm``.

        Cap: a regular x-y grid (x, y multiples of the spacing), z = sqrt(R² - x² - y²), each point
        standing for a surface element of spacing² R / z mm². Walls: a grid of (arc length, height)
        along the elliptical / circular edge, arc step the perimeter divided into the nearest
        whole number of spacings. Screws: a Cartesian grid of the spacing in the screw's own frame
        (x, y in the disk, z along the axis); their weights share ``mu * pi r² L`` equally, so a
        coarse grid keeps the screws' total attenuation.
        """
        spec = TransducerSpec() if spec is None else spec
        if not isinstance(spec, TransducerSpec):
            raise TypeError(f"spec must be a TransducerSpec, got {type(spec).__name__}")
        s = _check_spacing(spacing_mm)
        parts = [_cap_points(spec, s), _outer_wall_points(spec, s), _inner_wall_points(spec, s),
                 _screw_points(spec, s, _rim_screw_positions(spec), spec.screw_count)]
        points, weights, steps = _merge_parts(parts)
        return cls(spec=spec, spacing_mm=s, points=points, weights=weights, grid_step_mm=steps)

    @classmethod
    def build_physical(cls, spec: TransducerSpec | None = None, spacing_mm: float = 0.47, *,
                       deviation: ManufacturingDeviation | None = None,
                       rng: np.random.Generator) -> "TransducerModel":
        """The physical transducer: the digital model with its quadrants moved and extra screws.

        Each quadrant q gets ``T_q = Trans(c + t) Rot(r) Trans(-c)`` — a rotation by the rotation
        vector ``r ~ N(0, tilt_sd²)`` per component about the quadrant's centroid ``c`` (mean of its
        TRANSDUCER points), then an offset ``t ~ N(0, offset_sd²)`` per axis — drawn from ``rng`` in
        the order: 4x3 offsets, then 4x3 rotation vectors. The focal point is the mean of the
        perturbed sphere centres ``T_q @ 0``. Extra screws (on the probe mount, not perturbed)
        follow the digital model's screws in the SCREWS array, which otherwise keeps the digital
        model's point order.
        """
        deviation = ManufacturingDeviation() if deviation is None else deviation
        if not isinstance(deviation, ManufacturingDeviation):
            raise TypeError(f"deviation must be a ManufacturingDeviation, got {type(deviation).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        digital = cls.build(spec, spacing_mm)
        spec, s = digital.spec, digital.spacing_mm
        transforms = _quadrant_perturbations(digital, deviation, rng)
        points = {f: _apply_per_quadrant(p, transforms) for f, p in digital.points.items()}
        weights = dict(digital.weights)
        steps = dict(digital.grid_step_mm)
        if deviation.extra_screw_count:
            base = _mount_screw_positions(spec, deviation)
            extra = _screw_points(spec, s, base, deviation.extra_screw_count)
            points[Feature.SCREWS] = np.vstack([points[Feature.SCREWS], extra.points[Feature.SCREWS]])
            weights[Feature.SCREWS] = np.concatenate([weights[Feature.SCREWS], extra.weights[Feature.SCREWS]])
            steps[Feature.SCREWS] = max(steps[Feature.SCREWS], extra.steps[Feature.SCREWS])
        focal = transforms[:, :3, 3].mean(axis=0)
        return cls(spec=spec, spacing_mm=s, points=points, weights=weights, focal_point_mm=focal,
                   deviation=deviation, quadrant_transforms=transforms, grid_step_mm=steps)

    # --- access -------------------------------------------------------------------------------

    @property
    def n_points(self) -> dict:
        """``{Feature: number of points}``."""
        return {f: len(self.points[f]) for f in FEATURE_CLASSES}

    def only(self, *features: Feature) -> "TransducerModel":
        """The same model with the points of ``features`` only (the other classes empty), e.g. to
        rasterise each class's labels alone, free of the overlap priority of §II-B.2."""
        keep = set()
        for f in features:
            if Feature(f) not in FEATURE_CLASSES:
                raise ValueError(f"features must be point classes {[k.name for k in FEATURE_CLASSES]}, got {f!r}")
            keep.add(Feature(f))
        points = {f: self.points[f] if f in keep else np.zeros((0, 3)) for f in FEATURE_CLASSES}
        weights = {f: self.weights[f] if f in keep else np.zeros(0) for f in FEATURE_CLASSES}
        return replace(self, points=points, weights=weights)

    def all_points(self) -> tuple[np.ndarray, np.ndarray]:
        """All points ``(N, 3)`` mm and their classes ``(N,)`` uint8, concatenated in enum order."""
        pts = np.vstack([self.points[f] for f in FEATURE_CLASSES])
        classes = np.concatenate([np.full(len(self.points[f]), int(f), np.uint8) for f in FEATURE_CLASSES])
        return pts, classes

    def all_weights(self) -> np.ndarray:
        """All weights ``(N,)`` mm², in the order of :meth:`all_points`."""
        return np.concatenate([self.weights[f] for f in FEATURE_CLASSES])

    def __repr__(self) -> str:
        kind = "digital" if self.deviation is None else "physical"
        counts = ", ".join(f"{f.name}={n}" for f, n in self.n_points.items())
        return f"TransducerModel({kind}, spacing_mm={self.spacing_mm:g}, {counts})"


def quadrant_index(points_mm) -> np.ndarray:
    """Quadrant of each point (transducer frame): 0 (+x,+y), 1 (-x,+y), 2 (-x,-y), 3 (+x,-y).

    Points on a split plane (x = 0 or y = 0, inside the gaps) go to the + side.
    """
    p = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    right, top = p[:, 0] >= 0, p[:, 1] >= 0
    return np.where(top, np.where(right, 0, 1), np.where(right, 3, 2)).astype(np.intp)


def pose_facing(direction=(0.0, 1.0, 0.0), focal_point_mm=(0.0, 0.0, 0.0),
                axial_rotation_rad: float = 0.0) -> np.ndarray:
    """``T_carm_transducer`` of a transducer aimed along ``direction`` at ``focal_point_mm``.

    Args:
        direction: world (CBCT, LPS) vector from the transducer centre to the focal point — the
            paper's set-up, transducer above the supine patient in a water bath, is the default
            ``(0, 1, 0)`` (anterior to posterior): the transducer centre then sits at
            ``focal_point + (0, -R, 0)``. A :class:`~histostudy.imaging.carm.View` stands for its beam
            direction: the transducer between source and focal point, facing the detector en face.
        focal_point_mm: world position of the geometric focal point (the transducer origin).
        axial_rotation_rad: rotation about the transducer axis. At 0 the transducer's x (LR) axis
            is the world x axis projected on the aperture plane (world z when the axis is along x),
            so in the default set-up LR is the patient's left and TB (y) points to the head.
    """
    d = np.asarray(getattr(direction, "principal_direction", direction), dtype=np.float64).reshape(-1)
    norm = np.linalg.norm(d)
    if d.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"direction must be a non-zero finite 3-vector or a View, got {direction!r}")
    z = -d / norm
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = ref - ref.dot(z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ rotation_about_axis([0, 0, 1], float(axial_rotation_rad))
    return make_transform(R, focal_point_mm)


# --- building blocks ------------------------------------------------------------------------


@dataclass
class _Part:
    points: dict
    weights: dict
    steps: dict


def _check_spacing(spacing_mm) -> float:
    if isinstance(spacing_mm, bool) or not isinstance(spacing_mm, (int, float, np.integer, np.floating)):
        raise TypeError(f"spacing_mm must be a number in mm, got {spacing_mm!r}")
    s = float(spacing_mm)
    if not math.isfinite(s) or s <= 0:
        raise ValueError(f"spacing_mm must be finite and > 0 (mm), got {spacing_mm!r}")
    return s


def _part(classes: np.ndarray, pts: np.ndarray, wts: np.ndarray, steps: dict) -> _Part:
    points = {f: pts[classes == f] for f in FEATURE_CLASSES}
    weights = {f: wts[classes == f] for f in FEATURE_CLASSES}
    return _Part(points, weights, {f: steps[f] for f in steps if len(points[f])})


def _merge_parts(parts: list[_Part]) -> tuple[dict, dict, dict]:
    points = {f: np.vstack([p.points[f] for p in parts]) for f in FEATURE_CLASSES}
    weights = {f: np.concatenate([p.weights[f] for p in parts]) for f in FEATURE_CLASSES}
    steps = {f: max(p.steps[f] for p in parts if f in p.steps) for f in FEATURE_CLASSES
             if any(f in p.steps for p in parts)}
    return points, weights, steps


def _in_gap(spec: TransducerSpec, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    half = spec.gap_width_mm / 2
    return (np.abs(x) < half) | (np.abs(y) < half)


def _cap_points(spec: TransducerSpec, s: float) -> _Part:
    """Spherical cap inside the elliptical aperture, outside the cutout; classes by region."""
    a, b, R = spec.aperture_x_mm / 2, spec.aperture_y_mm / 2, spec.radius_mm
    rc = spec.cutout_diameter_mm / 2
    xs = s * np.arange(-math.floor(a / s), math.floor(a / s) + 1)
    ys = s * np.arange(-math.floor(b / s), math.floor(b / s) + 1)
    x, y = (g.ravel() for g in np.meshgrid(xs, ys))
    r2 = x * x + y * y
    keep = ((x / a) ** 2 + (y / b) ** 2 <= 1.0) & (r2 >= rc * rc)
    x, y, r2 = x[keep], y[keep], r2[keep]
    z = np.sqrt(R * R - r2)

    classes = np.full(len(x), int(Feature.TRANSDUCER), np.uint8)
    outer = (x / (a - spec.outer_band_mm)) ** 2 + (y / (b - spec.outer_band_mm)) ** 2 > 1.0
    classes[outer] = Feature.OUTER_BOUNDARY
    classes[r2 < (rc + spec.inner_band_mm) ** 2] = Feature.INNER_BOUNDARY
    classes[_in_gap(spec, x, y)] = Feature.GAPS

    area = s * s * R / z
    element = spec.element_mu_per_mm * spec.element_thickness_mm
    # The band is where the element edge rests on the housing's flange: element + rim material.
    band = element + spec.rim_mu_per_mm * spec.rim_thickness_mm
    mu_t = np.where(classes == Feature.TRANSDUCER, element, band)
    weights = np.where(classes == Feature.GAPS, 0.0, mu_t * area)
    steps = {f: s * R / z[classes == f].min() for f in FEATURE_CLASSES if np.any(classes == f)}
    return _part(classes, np.column_stack([x, y, z]), weights, steps)


def _arc_samples(x_of, y_of, length_hint: float, s: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Points at equal arc-length steps (about ``s``) along a closed curve ``(x(t), y(t))``, t in [0, 2pi)."""
    t = np.linspace(0.0, 2 * np.pi, max(4096, int(64 * length_hint / s)) + 1)
    seg = np.hypot(np.diff(x_of(t)), np.diff(y_of(t)))
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(8, int(round(arc[-1] / s)))
    step = arc[-1] / n
    # Half-step offset keeps samples off t = 0, which lies on the y = 0 split plane.
    tk = np.interp((np.arange(n) + 0.5) * step, arc, t)
    return x_of(tk), y_of(tk), step


def _wall(spec: TransducerSpec, s: float, x: np.ndarray, y: np.ndarray, arc_step: float,
          height: float, feature: Feature) -> _Part:
    """A cylindrical wall parallel to z rising ``height`` from the cap edge at ``(x, y)``."""
    if height <= 0 or len(x) == 0:
        return _part(np.zeros(0, np.uint8), np.zeros((0, 3)), np.zeros(0), {})
    n_h = max(1, int(round(height / s)))
    h = (np.arange(n_h) + 0.5) * height / n_h
    z0 = np.sqrt(spec.radius_mm ** 2 - x * x - y * y)
    pts = np.column_stack([np.repeat(x, n_h), np.repeat(y, n_h), (z0[:, None] + h[None, :]).ravel()])
    gap = _in_gap(spec, pts[:, 0], pts[:, 1])
    classes = np.where(gap, int(Feature.GAPS), int(feature)).astype(np.uint8)
    area = arc_step * height / n_h
    weights = np.where(gap, 0.0, spec.rim_mu_per_mm * spec.rim_thickness_mm * area)
    step = max(arc_step, height / n_h)
    return _part(classes, pts, weights, {feature: step, Feature.GAPS: step})


def _outer_wall_points(spec: TransducerSpec, s: float) -> _Part:
    a, b = spec.aperture_x_mm / 2, spec.aperture_y_mm / 2
    x, y, step = _arc_samples(lambda t: a * np.cos(t), lambda t: b * np.sin(t), 2 * np.pi * max(a, b), s)
    return _wall(spec, s, x, y, step, spec.outer_wall_height_mm, Feature.OUTER_BOUNDARY)


def _inner_wall_points(spec: TransducerSpec, s: float) -> _Part:
    rc = spec.cutout_diameter_mm / 2
    x, y, step = _arc_samples(lambda t: rc * np.cos(t), lambda t: rc * np.sin(t), 2 * np.pi * rc, s)
    return _wall(spec, s, x, y, step, spec.inner_wall_height_mm, Feature.INNER_BOUNDARY)


def _rim_screw_positions(spec: TransducerSpec) -> np.ndarray:
    """Screw bases ``(n, 3)``: middle of the outer band, on the cap surface."""
    n = spec.screw_count
    t = (np.arange(n) + 0.5) * 2 * np.pi / max(n, 1)
    x = (spec.aperture_x_mm / 2 - spec.outer_band_mm / 2) * np.cos(t)
    y = (spec.aperture_y_mm / 2 - spec.outer_band_mm / 2) * np.sin(t)
    return np.column_stack([x, y, np.sqrt(spec.radius_mm ** 2 - x * x - y * y)])


def _mount_screw_positions(spec: TransducerSpec, deviation: ManufacturingDeviation) -> np.ndarray:
    """Extra screw bases ``(n, 3)`` on the probe mount: a ring around the axis beyond the apex."""
    n = deviation.extra_screw_count
    t = (np.arange(n) + 0.5) * 2 * np.pi / max(n, 1)
    r = deviation.extra_screw_ring_radius_mm
    z = np.full(n, spec.radius_mm + deviation.extra_screw_height_mm)
    return np.column_stack([r * np.cos(t), r * np.sin(t), z])


def _screw_points(spec: TransducerSpec, s: float, bases: np.ndarray, count: int) -> _Part:
    """Solid cylinders (axis +z from each base) filled with a Cartesian grid of spacing ``s``."""
    if count == 0:
        return _part(np.zeros(0, np.uint8), np.zeros((0, 3)), np.zeros(0), {})
    r, length = spec.screw_diameter_mm / 2, spec.screw_length_mm
    k = math.floor(r / s)
    i, j = (g.ravel() for g in np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1)))
    disk = (i * i + j * j) * s * s <= r * r
    n_z = max(1, int(round(length / s)))
    local = np.column_stack([
        np.tile(i[disk] * s, n_z), np.tile(j[disk] * s, n_z),
        np.repeat((np.arange(n_z) + 0.5) * length / n_z, int(disk.sum())),
    ])
    pts = (bases[:, None, :] + local[None, :, :]).reshape(-1, 3)
    weight = spec.screw_mu_per_mm * np.pi * r * r * length / len(local)
    classes = np.full(len(pts), int(Feature.SCREWS), np.uint8)
    return _part(classes, pts, np.full(len(pts), weight), {Feature.SCREWS: max(s, length / n_z)})


def _quadrant_perturbations(digital: TransducerModel, deviation: ManufacturingDeviation,
                            rng: np.random.Generator) -> np.ndarray:
    offsets = rng.normal(0.0, deviation.quadrant_offset_sd_mm, size=(4, 3))
    rotvecs = rng.normal(0.0, np.deg2rad(deviation.quadrant_tilt_sd_deg), size=(4, 3))
    elements = digital.points[Feature.TRANSDUCER]
    quadrant = quadrant_index(elements)
    transforms = np.empty((4, 4, 4))
    for q in range(4):
        c = elements[quadrant == q].mean(axis=0)
        R = matrix_from_rotvec(rotvecs[q])
        transforms[q] = make_transform(R, c + offsets[q] - R @ c)
    return transforms


def _apply_per_quadrant(points: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    out = np.empty_like(points)
    quadrant = quadrant_index(points)
    for q in range(4):
        sel = quadrant == q
        T = transforms[q]
        out[sel] = points[sel] @ T[:3, :3].T + T[:3, 3]
    return out
