"""The transducer's point-cloud model (§II-B.1): one array of points per feature class in the transducer
frame (mm), each with an attenuation-weighted area (mm²); the digital model and its physical variant
(§IV). See docs/imaging.md, "The transducer model"."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .mesh import mesh_model_fields
from .physical import ManufacturingDeviation, physical_model_fields
from .sampling import (
    cap_points,
    check_spacing_mm,
    inner_wall_points,
    merge_parts,
    outer_wall_points,
    rim_screw_bases_mm,
    screw_points,
)
from .spec import FEATURE_CLASSES, Feature, TransducerSpec

__all__ = ["TransducerModel"]


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
        self.spacing_mm = check_spacing_mm(self.spacing_mm)
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
    def build(cls, spec: TransducerSpec | None = None, spacing_mm: float = 0.47) -> TransducerModel:
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
        s = check_spacing_mm(spacing_mm)
        parts = [cap_points(spec, s), outer_wall_points(spec, s), inner_wall_points(spec, s),
                 screw_points(spec, s, rim_screw_bases_mm(spec), spec.screw_count)]
        points, weights, steps = merge_parts(parts)
        return cls(spec=spec, spacing_mm=s, points=points, weights=weights, grid_step_mm=steps)

    @classmethod
    def build_physical(cls, spec: TransducerSpec | None = None, spacing_mm: float = 0.47, *,
                       deviation: ManufacturingDeviation | None = None,
                       rng: np.random.Generator) -> TransducerModel:
        """The physical transducer (§IV): the digital model of :meth:`build` with its quadrants moved
        and extra screws, drawn from ``rng`` as
        :func:`histostudy.transducer.physical.physical_model_fields` says."""
        deviation = ManufacturingDeviation() if deviation is None else deviation
        if not isinstance(deviation, ManufacturingDeviation):
            raise TypeError(f"deviation must be a ManufacturingDeviation, got {type(deviation).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return cls(**physical_model_fields(cls.build(spec, spacing_mm), deviation, rng))

    @classmethod
    def from_meshes(cls, meshes, *, spacing_mm: float = 0.47, mu_per_mm=None, units: str = "mm",
                    T_transducer_mesh=None, focal_point_mm=None,
                    spec: TransducerSpec | None = None) -> TransducerModel:
        """A model sampled from a lab's closed CAD surfaces (§II-B.1), as
        :mod:`histostudy.transducer.mesh` describes.

        Args:
            meshes: ``{Feature or class name ("screws"): mesh file or pyvista.PolyData}``, or one
                file / PolyData with a cell array ``"feature"`` (Feature values or names) per part.
            spacing_mm: sampling spacing (no sampled edge longer than twice it).
            mu_per_mm: ``{class: attenuation 1/mm}`` overriding
                :func:`~histostudy.transducer.mesh.default_mesh_mu_per_mm` (GAPS must stay 0).
            units: the files' length unit: "mm", "cm", "m" or "in".
            T_transducer_mesh: 4x4 rigid transform from the CAD frame (after ``units``) into the
                transducer frame (origin at the geometric focal point, +z towards the transducer;
                :mod:`histostudy.transducer.spec`); default identity.
            focal_point_mm: the acoustic focal point in the transducer frame; default zeros.
            spec: the :class:`TransducerSpec` whose fields the pose stages read (``radius_mm``,
                ``cutout_diameter_mm``, ``inner_band_mm`` for the conic orientation initialiser);
                default ``TransducerSpec()``, the paper's: a lab sets them to its transducer's.
        """
        return cls(**mesh_model_fields(meshes, spacing_mm=spacing_mm, mu_per_mm=mu_per_mm, units=units,
                                       T_transducer_mesh=T_transducer_mesh, focal_point_mm=focal_point_mm,
                                       spec=spec))

    # --- access -------------------------------------------------------------------------------

    @property
    def n_points(self) -> dict:
        """``{Feature: number of points}``."""
        return {f: len(self.points[f]) for f in FEATURE_CLASSES}

    def only(self, *features: Feature) -> TransducerModel:
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
