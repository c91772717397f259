"""Sampling the transducer's surfaces and solids into weighted points (§II-B.1), the building blocks of the
digital and physical models: points in mm, attenuation-weighted areas in mm², grid steps in mm."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .spec import FEATURE_CLASSES, Feature, TransducerSpec

__all__: list[str] = []


@dataclass
class SampledPart:
    """A piece of the model: ``points`` ``{Feature: (n, 3)}`` mm, ``weights`` ``{Feature: (n,)}`` mm²
    and ``steps`` ``{Feature: mm}``, the latter only for the classes the piece has points of."""

    points: dict
    weights: dict
    steps: dict


def check_spacing_mm(spacing_mm) -> float:
    """``spacing_mm`` as a float, or a TypeError / ValueError naming it."""
    if isinstance(spacing_mm, bool) or not isinstance(spacing_mm, (int, float, np.integer, np.floating)):
        raise TypeError(f"spacing_mm must be a number in mm, got {spacing_mm!r}")
    s = float(spacing_mm)
    if not math.isfinite(s) or s <= 0:
        raise ValueError(f"spacing_mm must be finite and > 0 (mm), got {spacing_mm!r}")
    return s


def _split_by_class(classes: np.ndarray, pts: np.ndarray, wts: np.ndarray, steps: dict) -> SampledPart:
    points = {f: pts[classes == f] for f in FEATURE_CLASSES}
    weights = {f: wts[classes == f] for f in FEATURE_CLASSES}
    return SampledPart(points, weights, {f: steps[f] for f in steps if len(points[f])})


def merge_parts(parts: list[SampledPart]) -> tuple[dict, dict, dict]:
    """``(points, weights, steps)`` of ``parts`` stacked per class in the order given."""
    points = {f: np.vstack([p.points[f] for p in parts]) for f in FEATURE_CLASSES}
    weights = {f: np.concatenate([p.weights[f] for p in parts]) for f in FEATURE_CLASSES}
    steps = {f: max(p.steps[f] for p in parts if f in p.steps) for f in FEATURE_CLASSES
             if any(f in p.steps for p in parts)}
    return points, weights, steps


def _in_gap(spec: TransducerSpec, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    half = spec.gap_width_mm / 2
    return (np.abs(x) < half) | (np.abs(y) < half)


def cap_points(spec: TransducerSpec, s: float) -> SampledPart:
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
    return _split_by_class(classes, np.column_stack([x, y, z]), weights, steps)


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
          height: float, feature: Feature) -> SampledPart:
    """A cylindrical wall parallel to z rising ``height`` from the cap edge at ``(x, y)``."""
    if height <= 0 or len(x) == 0:
        return _split_by_class(np.zeros(0, np.uint8), np.zeros((0, 3)), np.zeros(0), {})
    n_h = max(1, int(round(height / s)))
    h = (np.arange(n_h) + 0.5) * height / n_h
    z0 = np.sqrt(spec.radius_mm ** 2 - x * x - y * y)
    pts = np.column_stack([np.repeat(x, n_h), np.repeat(y, n_h), (z0[:, None] + h[None, :]).ravel()])
    gap = _in_gap(spec, pts[:, 0], pts[:, 1])
    classes = np.where(gap, int(Feature.GAPS), int(feature)).astype(np.uint8)
    area = arc_step * height / n_h
    weights = np.where(gap, 0.0, spec.rim_mu_per_mm * spec.rim_thickness_mm * area)
    step = max(arc_step, height / n_h)
    return _split_by_class(classes, pts, weights, {feature: step, Feature.GAPS: step})


def outer_wall_points(spec: TransducerSpec, s: float) -> SampledPart:
    a, b = spec.aperture_x_mm / 2, spec.aperture_y_mm / 2
    x, y, step = _arc_samples(lambda t: a * np.cos(t), lambda t: b * np.sin(t), 2 * np.pi * max(a, b), s)
    return _wall(spec, s, x, y, step, spec.outer_wall_height_mm, Feature.OUTER_BOUNDARY)


def inner_wall_points(spec: TransducerSpec, s: float) -> SampledPart:
    rc = spec.cutout_diameter_mm / 2
    x, y, step = _arc_samples(lambda t: rc * np.cos(t), lambda t: rc * np.sin(t), 2 * np.pi * rc, s)
    return _wall(spec, s, x, y, step, spec.inner_wall_height_mm, Feature.INNER_BOUNDARY)


def rim_screw_bases_mm(spec: TransducerSpec) -> np.ndarray:
    """Screw bases ``(n, 3)``: middle of the outer band, on the cap surface."""
    n = spec.screw_count
    t = (np.arange(n) + 0.5) * 2 * np.pi / max(n, 1)
    x = (spec.aperture_x_mm / 2 - spec.outer_band_mm / 2) * np.cos(t)
    y = (spec.aperture_y_mm / 2 - spec.outer_band_mm / 2) * np.sin(t)
    return np.column_stack([x, y, np.sqrt(spec.radius_mm ** 2 - x * x - y * y)])


def screw_points(spec: TransducerSpec, s: float, bases: np.ndarray, count: int) -> SampledPart:
    """Solid cylinders (axis +z from each base) filled with a Cartesian grid of spacing ``s``."""
    if count == 0:
        return _split_by_class(np.zeros(0, np.uint8), np.zeros((0, 3)), np.zeros(0), {})
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
    return _split_by_class(classes, pts, np.full(len(pts), weight), {Feature.SCREWS: max(s, length / n_z)})
