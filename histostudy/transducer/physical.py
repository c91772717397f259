"""The physical transducer (§IV): how the real one differed from its digital model (quadrants off their
nominal place, screws outside the CBCT's field of view), as a :class:`ManufacturingDeviation` (mm, deg)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from histostudy.geometry import make_transform, matrix_from_rotvec

from .sampling import screw_points
from .spec import Feature, TransducerSpec, quadrant_index

__all__ = ["ManufacturingDeviation"]


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


def physical_model_fields(digital, deviation: ManufacturingDeviation, rng: np.random.Generator) -> dict:
    """The fields of the physical ``TransducerModel`` made from the ``digital`` one.

    Each quadrant q gets ``T_q = Trans(c + t) Rot(r) Trans(-c)`` — a rotation by the rotation
    vector ``r ~ N(0, tilt_sd²)`` per component about the quadrant's centroid ``c`` (mean of its
    TRANSDUCER points), then an offset ``t ~ N(0, offset_sd²)`` per axis — drawn from ``rng`` in
    the order: 4x3 offsets, then 4x3 rotation vectors. The focal point is the mean of the
    perturbed sphere centres ``T_q @ 0``. Extra screws (on the probe mount, not perturbed)
    follow the digital model's screws in the SCREWS array, which otherwise keeps the digital
    model's point order. Returns the keyword arguments of ``TransducerModel``.
    """
    spec, s = digital.spec, digital.spacing_mm
    transforms = _quadrant_perturbations(digital.points[Feature.TRANSDUCER], deviation, rng)
    points = {f: _apply_per_quadrant(p, transforms) for f, p in digital.points.items()}
    weights = dict(digital.weights)
    steps = dict(digital.grid_step_mm)
    if deviation.extra_screw_count:
        base = _mount_screw_bases_mm(spec, deviation)
        extra = screw_points(spec, s, base, deviation.extra_screw_count)
        points[Feature.SCREWS] = np.vstack([points[Feature.SCREWS], extra.points[Feature.SCREWS]])
        weights[Feature.SCREWS] = np.concatenate([weights[Feature.SCREWS], extra.weights[Feature.SCREWS]])
        steps[Feature.SCREWS] = max(steps[Feature.SCREWS], extra.steps[Feature.SCREWS])
    focal = transforms[:, :3, 3].mean(axis=0)
    return dict(spec=spec, spacing_mm=s, points=points, weights=weights, focal_point_mm=focal,
                deviation=deviation, quadrant_transforms=transforms, grid_step_mm=steps)


def _mount_screw_bases_mm(spec: TransducerSpec, deviation: ManufacturingDeviation) -> np.ndarray:
    """Extra screw bases ``(n, 3)`` on the probe mount: a ring around the axis beyond the apex."""
    n = deviation.extra_screw_count
    t = (np.arange(n) + 0.5) * 2 * np.pi / max(n, 1)
    r = deviation.extra_screw_ring_radius_mm
    z = np.full(n, spec.radius_mm + deviation.extra_screw_height_mm)
    return np.column_stack([r * np.cos(t), r * np.sin(t), z])


def _quadrant_perturbations(elements: np.ndarray, deviation: ManufacturingDeviation,
                            rng: np.random.Generator) -> np.ndarray:
    """``(4, 4, 4)`` nominal -> physical transforms of the quadrants; ``elements``: the digital
    model's TRANSDUCER points ``(n, 3)`` mm, whose per-quadrant means are the rotation centres."""
    offsets = rng.normal(0.0, deviation.quadrant_offset_sd_mm, size=(4, 3))
    rotvecs = rng.normal(0.0, np.deg2rad(deviation.quadrant_tilt_sd_deg), size=(4, 3))
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
