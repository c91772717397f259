"""The parametric transducer written as closed surface meshes, one file per feature class (§II-B.1): the
inverse of ``TransducerModel.from_meshes``, whose solids weigh what the parametric model gives each class."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from histostudy.core import atomic_path

from .mesh import default_mesh_mu_per_mm
from .sampling import rim_screw_bases_mm
from .spec import FEATURE_CLASSES, Feature, TransducerSpec

__all__ = ["export_meshes"]

#: File formats pyvista writes and reads back as surface meshes.
MESH_FORMATS = ("stl", "ply", "obj", "vtp", "vtk")
_SCREW_SIDES = 48
#: The gap sheets' thickness (mm): thin, see the module docstring.
GAP_THICKNESS_MM = 0.2


def export_meshes(model_or_spec, folder: str | os.PathLike, *, format: str = "stl",
                  max_edge_mm: float = 2.0) -> dict:
    """Write the parametric model's classes as closed surface meshes, one file per class.

    Args:
        model_or_spec: a :class:`TransducerSpec`, or a digital ``TransducerModel`` (its ``spec``);
            a physical model (quadrants moved, extra screws) is refused: only the parametric
            geometry is written.
        folder: where the files go (created if needed): ``transducer.<format>``,
            ``outer_boundary.<format>``, ``inner_boundary.<format>``, ``gaps.<format>`` and
            ``screws.<format>`` (no screws file when ``spec.screw_count`` is 0). Each file is
            written atomically (:func:`histostudy.core.atomic_path`), with the umask's mode.
        format: one of :data:`MESH_FORMATS`.
        max_edge_mm: the longest triangle edge of the cap and wall tessellation (the sphere's
            chord error is ``max_edge_mm**2 / (8 R)``, 0.004 mm at 2 mm).

    Returns:
        ``{Feature: Path}`` of the files written, in mm in the transducer frame.
    """
    spec = _spec_of(model_or_spec)
    if format not in MESH_FORMATS:
        raise ValueError(f"format must be one of {MESH_FORMATS}, got {format!r}")
    if isinstance(max_edge_mm, bool) or not isinstance(max_edge_mm, (int, float, np.integer, np.floating)) \
            or not math.isfinite(max_edge_mm) or max_edge_mm <= 0:
        raise ValueError(f"max_edge_mm must be a finite number > 0 (mm), got {max_edge_mm!r}")
    import pyvista as pv  # only here: importing histostudy.transducer stays light

    written = {}
    for feature, (points, triangles) in class_surfaces(spec, float(max_edge_mm)).items():
        if len(triangles) == 0:
            continue
        faces = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
        mesh = pv.PolyData(points, faces)
        path = Path(folder) / f"{feature.name.lower()}.{format}"
        with atomic_path(path) as tmp:  # the writer picks its format from tmp's suffix, kept by atomic_path
            mesh.save(tmp, binary=True)
        written[feature] = path
    return written


def _spec_of(model_or_spec) -> TransducerSpec:
    if isinstance(model_or_spec, TransducerSpec):
        return model_or_spec
    spec = getattr(model_or_spec, "spec", None)
    if not isinstance(spec, TransducerSpec):
        raise TypeError(f"model_or_spec must be a TransducerSpec or a TransducerModel, got "
                        f"{type(model_or_spec).__name__}")
    if getattr(model_or_spec, "deviation", None) is not None:
        raise ValueError("model_or_spec is a physical model (quadrants moved, extra screws); export_meshes "
                         "writes the parametric geometry only: pass the digital model or its spec")
    return spec


def class_surfaces(spec: TransducerSpec, max_edge_mm: float) -> dict:
    """``{Feature: (points (n, 3) mm, triangles (m, 3) int)}``: each class's solids as one closed,
    outward-oriented triangle surface (disjoint parts) in the transducer frame."""
    mu = default_mesh_mu_per_mm(spec)
    a, b, rc = spec.aperture_x_mm / 2, spec.aperture_y_mm / 2, spec.cutout_diameter_mm / 2
    wo, wi = spec.outer_band_mm, spec.inner_band_mm
    # The walls' equivalent thickness in the boundary material (module docstring); with no
    # attenuating material at all they keep the rim's own thickness (and weigh nothing).
    mu_b = mu[Feature.OUTER_BOUNDARY]
    wall = spec.rim_thickness_mm * spec.rim_mu_per_mm / mu_b if mu_b > 0 else spec.rim_thickness_mm
    if max(a, b) + wall >= spec.radius_mm - spec.element_thickness_mm / 2:
        raise ValueError(f"the aperture (half-widths {a:g}, {b:g} mm) with its wall reaches the inner sphere of "
                         f"radius {spec.radius_mm - spec.element_thickness_mm / 2:g} mm: no slab to export there")

    def ellipse(grow):
        return ("ellipse", a + grow, b + grow)

    def circle(r):
        return ("circle", r)

    walls = wall > 0
    outer_wall = [("outer_wall", ellipse(wall))] if walls and spec.outer_wall_height_mm > 0 else []
    inner_start = [circle(rc - wall), ("inner_wall", circle(rc))] if walls and spec.inner_wall_height_mm > 0 \
        else [circle(rc)]
    # Each piece: its curves from the inside out, each after the first with the kind of the
    # segment that ends at it.
    pieces = {
        Feature.TRANSDUCER: [circle(rc + wi), ("shell", ellipse(-wo))],
        Feature.OUTER_BOUNDARY: [ellipse(-wo), ("shell", ellipse(0.0)), *outer_wall],
        Feature.INNER_BOUNDARY: [*inner_start, ("shell", circle(rc + wi))],
    }
    gap_curves = [*inner_start, ("shell", ellipse(0.0)), *outer_wall]
    out = {}
    for feature in FEATURE_CLASSES:
        parts = []
        if feature in pieces:
            for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):  # the quadrant order of quadrant_index
                parts.append(_quadrant_piece(spec, pieces[feature], sx, sy, max_edge_mm))
        elif feature is Feature.GAPS and spec.gap_width_mm > 0:
            for axis in range(2):
                for sign in (1, -1):
                    parts.append(_arm_piece(spec, gap_curves, axis, sign, max_edge_mm))
        elif feature is Feature.SCREWS:
            for base in rim_screw_bases_mm(spec)[: spec.screw_count]:
                parts.append(_cylinder(base, spec.screw_diameter_mm / 2, spec.screw_length_mm))
        out[feature] = _concatenate(parts)
    return out


# --- solids over the cap: columns between two heights above a plan-view grid -----------------


def _ray_to_curve(curve, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Distance ``rho >= 0`` along the plan rays ``c + rho d`` (``(n, 2)`` each, ``|d| = 1``) to
    the curve, a circle ``("circle", r)`` or an ellipse ``("ellipse", A, B)`` centred on the axis."""
    if curve[0] == "circle":
        scale = np.array([1.0, 1.0]) / curve[1]
    else:
        scale = np.array([1.0 / curve[1], 1.0 / curve[2]])
    cs, ds = c * scale, d * scale
    alpha, beta, gamma = (ds * ds).sum(1), (cs * ds).sum(1), (cs * cs).sum(1) - 1.0
    return (-beta + np.sqrt(beta * beta - alpha * gamma)) / alpha


def _column_piece(spec: TransducerSpec, curves: list, c: np.ndarray, d: np.ndarray, max_edge_mm: float,
                  thickness_mm: float):
    """The solid over the plan region swept by the rays ``c + rho d`` between ``curves[0]`` and
    ``curves[-1]``; per segment, a cap slab (``"shell"``) or a wall (``"outer_wall"``,
    ``"inner_wall"``) of that wall's height above the cap sphere."""
    rhos = [_ray_to_curve(curves[0], c, d)] + [_ray_to_curve(curve, c, d) for _, curve in curves[1:]]
    s_list: list = []
    kinds: list[str] = []
    for k, (kind, _) in enumerate(curves[1:]):
        n = max(1, math.ceil((rhos[k + 1] - rhos[k]).max() / max_edge_mm))
        u = np.linspace(0.0, 1.0, n + 1)
        if k and kind == kinds[-1]:
            u = u[1:]
        # a segment of another kind starts with its own copy of the breakpoint: the vertical step
        # there joins the slab's and the wall's different heights
        s_list.append(rhos[k][None, :] + u[:, None] * (rhos[k + 1] - rhos[k])[None, :])
        kinds += [kind] * len(u)
    rho = np.vstack(s_list)
    x, y = c[None, :, 0] + rho * d[None, :, 0], c[None, :, 1] + rho * d[None, :, 1]
    r2 = x * x + y * y
    R, half = spec.radius_mm, thickness_mm / 2
    is_wall = np.array([k != "shell" for k in kinds])[:, None]
    height = np.array([spec.outer_wall_height_mm if k == "outer_wall" else spec.inner_wall_height_mm
                       for k in kinds])[:, None]
    mid = np.sqrt(R * R - r2)
    z_bottom = np.where(is_wall, mid, np.sqrt((R - half) ** 2 - r2))
    z_top = np.where(is_wall, mid + height, np.sqrt((R + half) ** 2 - r2))
    return _column_solid(x, y, z_bottom, z_top)


def _quadrant_piece(spec, curves, sx: int, sy: int, max_edge_mm: float):
    """One quadrant's piece: rays from the quadrant's gap corner ``(sx g/2, sy g/2)``, so its two
    straight sides are exactly the gap edges ``x = sx g/2`` and ``y = sy g/2``."""
    g = spec.gap_width_mm / 2
    corner = np.array([sx * g, sy * g])

    def outermost(phi):  # the piece's outer edge, whose arc length sets the rays' spacing
        d = _dirs(phi, sx, sy)
        return corner + _ray_to_curve(curves[-1][1], np.tile(corner, (len(phi), 1)), d)[:, None] * d

    phi = _equal_arc(outermost, 0.0, math.pi / 2, max_edge_mm)
    return _column_piece(spec, curves, np.tile(corner, (len(phi), 1)), _dirs(phi, sx, sy), max_edge_mm,
                         spec.element_thickness_mm)


def _dirs(phi: np.ndarray, sx: int, sy: int) -> np.ndarray:
    return np.column_stack([sx * np.cos(phi), sy * np.sin(phi)])


def _arm_piece(spec, curves, axis: int, sign: int, max_edge_mm: float):
    """One arm of the gap cross: rays parallel to the ``axis`` (0: x, 1: y) on the ``sign`` side,
    from across the stripe ``|other| <= g/2``."""
    g = spec.gap_width_mm / 2
    n = max(1, math.ceil(2 * g / max_edge_mm))
    across = np.linspace(-g, g, n + 1) * (sign if axis == 0 else -sign)  # one handedness for all arms
    c = np.zeros((n + 1, 2))
    c[:, 1 - axis] = across
    d = np.zeros((n + 1, 2))
    d[:, axis] = sign
    return _column_piece(spec, curves, c, d, max_edge_mm, GAP_THICKNESS_MM)


def _equal_arc(curve_of, t0: float, t1: float, step: float) -> np.ndarray:
    """Parameters in ``[t0, t1]`` at equal arc-length steps of at most ``step`` along ``curve_of``."""
    t = np.linspace(t0, t1, 4097)
    p = curve_of(t)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    n = max(2, math.ceil(arc[-1] / step))
    return np.interp(np.linspace(0.0, arc[-1], n + 1), arc, t)


def _column_solid(x, y, z_bottom, z_top):
    """The closed surface of ``{(x, y, z): z_bottom <= z <= z_top}`` over a structured plan grid
    ``(n_s, n_t)``: top and bottom grids, joined along the grid's border loop."""
    n_s, n_t = x.shape
    off = n_s * n_t
    points = np.vstack([np.column_stack([x.ravel(), y.ravel(), z_top.ravel()]),
                        np.column_stack([x.ravel(), y.ravel(), z_bottom.ravel()])])
    idx = np.arange(off).reshape(n_s, n_t)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    loop = np.concatenate([idx[:, 0], idx[-1, 1:], idx[-2::-1, -1], idx[0, -2:0:-1]])
    nxt = np.roll(loop, -1)
    quads = np.vstack([np.column_stack([a, b, c, d]), np.column_stack([a, d, c, b]) + off,
                       np.column_stack([nxt, loop, loop + off, nxt + off])])
    triangles = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return _outward(points, triangles)


def _cylinder(base: np.ndarray, radius: float, length: float):
    """A closed cylinder along +z from ``base``; the polygon's area is ``pi radius^2``."""
    n = _SCREW_SIDES
    r = radius * math.sqrt(2 * math.pi / (n * math.sin(2 * math.pi / n)))
    t = 2 * math.pi * np.arange(n) / n
    ring = np.column_stack([r * np.cos(t), r * np.sin(t), np.zeros(n)])
    points = np.vstack([ring, ring + [0, 0, length], np.array([[0.0, 0.0, 0.0], [0.0, 0.0, length]])]) + base
    i, j = np.arange(n), (np.arange(n) + 1) % n
    bottom, top = np.full(n, 2 * n), np.full(n, 2 * n + 1)
    triangles = np.vstack([np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n]),
                           np.column_stack([bottom, j, i]), np.column_stack([top, i + n, j + n])])
    return _outward(points, triangles)


def _outward(points: np.ndarray, triangles: np.ndarray):
    """Flip a consistently oriented closed surface so its normals point out (positive volume)."""
    p = points[triangles]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    return points, (triangles if volume > 0 else triangles[:, ::-1].copy())


def _concatenate(parts: list):
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    offsets = np.cumsum([0] + [len(p) for p, _ in parts[:-1]])
    return (np.vstack([p for p, _ in parts]),
            np.vstack([t + o for (_, t), o in zip(parts, offsets)]).astype(np.int64))
