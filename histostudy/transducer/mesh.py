"""A transducer model from a lab's closed CAD meshes (§II-B.1), one feature class per part, sampled into
weighted points in the transducer frame (mm); what is refused is named (docs/imaging.md, "A transducer
from CAD meshes")."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from histostudy.geometry import check_rigid

from .sampling import check_spacing_mm
from .spec import FEATURE_CLASSES, Feature, TransducerSpec

__all__ = ["default_mesh_mu_per_mm"]

#: Length units a mesh file may be in, as mm per unit.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
#: A histotripsy transducer spans centimetres to decimetres: meshes spanning less than this many
#: mm, read as mm, are almost surely in metres (or cm, in).
MIN_SPAN_MM = 10.0
#: The cell array naming each part's class in a single mesh (Feature values or names).
FEATURE_ARRAY = "feature"
#: The longest sampled edge over ``spacing_mm`` (module docstring).
EDGE_OVER_SPACING = 2.0
#: A ray direction with no special alignment to CAD axes, for the inside tests of nesting.
_RAY = np.array([0.8017837, 0.5345225, 0.2672612])


def default_mesh_mu_per_mm(spec: TransducerSpec | None = None) -> dict:
    """The attenuation (1/mm) of each class's material that ``from_meshes`` assumes by default.

    From ``spec`` (default ``TransducerSpec()``): TRANSDUCER ``element_mu_per_mm`` (1.4, lead-based
    ceramic); OUTER_ and INNER_BOUNDARY one material for the band where the element rests on the
    housing flange, ``element_mu + rim_mu * rim_thickness / element_thickness`` (1.6: the
    parametric band's attenuation per element thickness; the rim alone is 0.2); GAPS 0 (no
    material); SCREWS ``screw_mu_per_mm`` (0.4, steel). A lab whose parts are of other materials
    passes its own ``mu_per_mm``.
    """
    spec = TransducerSpec() if spec is None else spec
    if not isinstance(spec, TransducerSpec):
        raise TypeError(f"spec must be a TransducerSpec, got {type(spec).__name__}")
    band = spec.element_mu_per_mm + spec.rim_mu_per_mm * spec.rim_thickness_mm / spec.element_thickness_mm
    return {Feature.TRANSDUCER: spec.element_mu_per_mm, Feature.OUTER_BOUNDARY: band,
            Feature.INNER_BOUNDARY: band, Feature.GAPS: 0.0, Feature.SCREWS: spec.screw_mu_per_mm}


def mesh_model_fields(meshes, *, spacing_mm=0.47, mu_per_mm=None, units="mm", T_transducer_mesh=None,
                      focal_point_mm=None, spec=None) -> dict:
    """The keyword arguments of ``TransducerModel`` for
    :meth:`~histostudy.transducer.digital.TransducerModel.from_meshes` (see there)."""
    spec = TransducerSpec() if spec is None else spec
    if not isinstance(spec, TransducerSpec):
        raise TypeError(f"spec must be a TransducerSpec, got {type(spec).__name__}")
    s = check_spacing_mm(spacing_mm)
    if units not in UNITS_MM:
        raise ValueError(f"units must be one of {sorted(UNITS_MM)}, got {units!r}")
    T = np.eye(4) if T_transducer_mesh is None else check_rigid(T_transducer_mesh, "T_transducer_mesh")
    focal = np.zeros(3) if focal_point_mm is None else np.asarray(focal_point_mm, dtype=np.float64).reshape(-1)
    if focal.shape != (3,) or not np.all(np.isfinite(focal)):
        raise ValueError(f"focal_point_mm must be 3 finite numbers (mm, transducer frame), got {focal_point_mm!r}")
    mu = _mu_per_class(mu_per_mm, spec)

    surfaces = _read_sources(meshes, UNITS_MM[units])
    lo = np.min([p.min(axis=0) for _, p, _, _ in surfaces], axis=0)
    hi = np.max([p.max(axis=0) for _, p, _, _ in surfaces], axis=0)
    span = float((hi - lo).max())
    if span < MIN_SPAN_MM:
        labels = ", ".join(label for label, _, _, _ in surfaces)
        raise ValueError(f"the meshes ({labels}) span {span:.4g} mm read as units={units!r}; a histotripsy "
                         f"transducer spans centimetres to decimetres (>= {MIN_SPAN_MM:g} mm): are they in "
                         f"metres? pass units='m' (or 'cm', 'in')")

    parts: dict[Feature, list] = {f: [] for f in FEATURE_CLASSES}
    for label, points, triangles, classes in surfaces:
        points = points @ T[:3, :3].T + T[:3, 3]
        for feature, part_points, part_triangles in _closed_components(label, points, triangles, classes):
            parts[feature].append((part_points, part_triangles, label))
    points, weights, steps = {}, {}, {}
    for feature in FEATURE_CLASSES:
        points[feature], weights[feature], steps[feature] = _sample_class(parts[feature], mu[feature], s)
    return dict(spec=spec, spacing_mm=s, points=points, weights=weights, focal_point_mm=focal,
                grid_step_mm={f: v for f, v in steps.items() if v is not None})


# --- inputs -----------------------------------------------------------------------------------


def feature_of(key, where: str) -> Feature:
    """A point class from a :class:`Feature`, its value or its name (any case, ``-`` or space for
    ``_``); a ValueError naming ``where`` otherwise."""
    names = [f.name.lower() for f in FEATURE_CLASSES]
    if isinstance(key, str):
        name = key.strip().lower().replace("-", "_").replace(" ", "_")
        if name in names:
            return Feature[name.upper()]
    elif isinstance(key, (int, np.integer, float, np.floating)) and not isinstance(key, bool) \
            and float(key) in [float(f) for f in FEATURE_CLASSES]:  # floats too: some formats store floats
        return Feature(int(key))
    raise ValueError(f"{where}: unknown feature class {key!r}; expected one of {names} or their Feature values "
                     f"{[int(f) for f in FEATURE_CLASSES]}")


def _mu_per_class(mu_per_mm, spec: TransducerSpec) -> dict:
    mu = default_mesh_mu_per_mm(spec)
    if mu_per_mm is None:
        return mu
    if not isinstance(mu_per_mm, Mapping):
        raise TypeError(f"mu_per_mm must be a mapping {{Feature or name: 1/mm}}, got {type(mu_per_mm).__name__}")
    for key, value in mu_per_mm.items():
        feature = feature_of(key, f"mu_per_mm key {key!r}")
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                or not math.isfinite(value) or value < 0:
            raise ValueError(f"mu_per_mm[{key!r}] must be a finite attenuation >= 0 (1/mm), got {value!r}")
        if feature is Feature.GAPS and value != 0:
            raise ValueError(f"mu_per_mm[{key!r}] must be 0: GAPS mark the absence of material, got {value!r}")
        mu[feature] = float(value)
    return mu


def _read_sources(meshes, mm_per_unit: float) -> list:
    """``[(label, points (n, 3) mm, triangles (m, 3), classes (m,) uint8)]``, one per mesh given."""
    if isinstance(meshes, Mapping):
        if not meshes:
            raise ValueError("meshes is an empty mapping; expected {feature class: mesh file or pyvista.PolyData}")
        out: list = []
        seen: dict = {}
        for key, source in meshes.items():
            feature = feature_of(key, f"meshes key {key!r}")
            if feature in seen:
                raise ValueError(f"meshes keys {seen[feature]!r} and {key!r} both name {feature.name}; give one "
                                 f"mesh per class (several parts may share a file)")
            seen[feature] = key
            label = f"meshes[{key!r}]" + (f" = {source}" if isinstance(source, (str, os.PathLike)) else "")
            points, triangles, _ = _read_mesh(source, label, mm_per_unit)
            out.append((label, points, triangles, np.full(len(triangles), int(feature), np.uint8)))
        return out
    label = str(meshes) if isinstance(meshes, (str, os.PathLike)) else "meshes"
    points, triangles, cell_classes = _read_mesh(meshes, label, mm_per_unit)
    if cell_classes is None:
        raise ValueError(f"{label}: a single mesh needs a cell array {FEATURE_ARRAY!r} giving each part's class "
                         f"(Feature values or names); or pass a mapping {{class: mesh}}")
    values, inverse = np.unique(cell_classes, return_inverse=True)
    where = f"{label} cell array {FEATURE_ARRAY!r}"
    classes = np.array([int(feature_of(v.item() if hasattr(v, "item") else v, where)) for v in values],
                       np.uint8)[inverse.reshape(-1)]
    return [(label, points, triangles, classes)]


def _read_mesh(source, label: str, mm_per_unit: float):
    """``(points mm, triangles, cell classes or None)`` of a mesh file or pyvista dataset; exact
    duplicate points merged so that parts connect through shared vertices."""
    import pyvista as pv  # only here: importing histostudy.transducer stays light

    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"{label}: mesh file not found")
        try:
            data = pv.read(path)
        except Exception as exc:  # pyvista raises several types for unreadable or unknown files
            raise ValueError(f"{label}: pyvista cannot read it as a mesh ({exc})") from exc
    elif isinstance(source, (pv.DataSet, pv.MultiBlock)):
        data = source
    else:
        raise TypeError(f"{label}: expected a mesh file path or a pyvista.PolyData, got {type(source).__name__}")
    if isinstance(data, pv.MultiBlock):
        data = data.combine() if len(data) else pv.PolyData()
    if not isinstance(data, pv.PolyData):
        data = data.extract_surface()
    tri = data.triangulate() if data.n_cells else data
    faces = np.asarray(tri.faces).reshape(-1, 4) if tri.n_cells else np.zeros((0, 4), np.int64)
    if len(faces) == 0:
        raise ValueError(f"{label}: the mesh is empty (no surface triangles); expected closed surfaces")
    if np.any(faces[:, 0] != 3) or len(faces) != tri.n_cells:
        raise ValueError(f"{label}: the mesh holds cells other than polygons after triangulation")
    points = np.asarray(tri.points, dtype=np.float64)
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        raise ValueError(f"{label}: {int(bad.sum())} of its {len(points)} points are not finite (NaN or inf); "
                         f"expected finite coordinates")
    classes = tri.cell_data[FEATURE_ARRAY] if FEATURE_ARRAY in tri.cell_data else None
    unique, inverse = _unique_rows(points)
    triangles = inverse[faces[:, 1:]]
    # a triangle whose corners merged into fewer than three points has no area and no edges of its own
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) \
        & (triangles[:, 0] != triangles[:, 2])
    return unique * mm_per_unit, triangles[keep], None if classes is None else np.asarray(classes)[keep]


# --- parts: closed, consistently oriented surfaces --------------------------------------------


def _closed_components(label: str, points: np.ndarray, triangles: np.ndarray, classes: np.ndarray) -> list:
    """``[(Feature, points, triangles)]``, one per connected surface (parts touching at a vertex
    count as one), each checked closed, of one class and consistently oriented."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    starts, ends = triangles.ravel(), triangles[:, [1, 2, 0]].ravel()  # edge 3i + k: corner k -> k + 1
    graph = coo_matrix((np.ones(len(starts)), (starts, ends)), shape=(len(points), len(points)))
    component = connected_components(graph, directed=False)[1][triangles[:, 0]]
    edges, edge_index, counts = np.unique(_edge_keys(starts, ends, len(points)), return_inverse=True,
                                          return_counts=True)
    # A closed surface has every edge shared by an even number of faces (2; 4 where parts touch).
    open_edges = np.flatnonzero(counts % 2 == 1)
    ids = np.unique(component)
    if len(open_edges):
        open_parts = np.unique(component[np.flatnonzero(np.isin(edge_index, open_edges)) // 3])
        closed = len(ids) - len(open_parts)
        raise ValueError(f"{label}: {len(open_edges)} open edges (used by one face) in {len(open_parts)} of its "
                         f"{len(ids)} surfaces ({'no' if closed == 0 else closed} closed); expected closed "
                         f"surfaces, each part a solid with a volume")
    # Consistent orientation: each edge is run through as often in one direction as in the other.
    forward = np.where(starts < ends, 1, -1)
    unbalanced = np.bincount(edge_index, weights=forward, minlength=len(edges)) != 0
    out = []
    for c in ids:
        mine = component == c
        part_classes = np.unique(classes[mine])
        if len(part_classes) > 1:
            names = [Feature(int(k)).name for k in part_classes]
            raise ValueError(f"{label}: one closed surface carries the classes {names}; expected one class per "
                             f"part")
        tris = triangles[mine]
        if unbalanced[edge_index[np.repeat(mine, 3)]].any():
            tris = _orient_consistently(points, tris, label)
        out.append((Feature(int(part_classes[0])), points, tris))
    return out


def _orient_consistently(points: np.ndarray, triangles: np.ndarray, label: str) -> np.ndarray:
    """The triangles of one closed surface reordered to one orientation (VTK's normals filter), or
    a ValueError when no orientation is consistent (a non-orientable or self-touching surface)."""
    import pyvista as pv

    mesh = pv.PolyData(points, np.column_stack([np.full(len(triangles), 3), triangles]).ravel())
    fixed = mesh.compute_normals(cell_normals=False, point_normals=True, split_vertices=False,
                                 consistent_normals=True, auto_orient_normals=False)
    tris = np.asarray(fixed.faces).reshape(-1, 4)[:, 1:]
    starts, ends = tris.ravel(), tris[:, [1, 2, 0]].ravel()
    _, index = np.unique(_edge_keys(starts, ends, len(points)), return_inverse=True)
    if len(tris) != len(triangles) or np.any(np.bincount(index, weights=np.where(starts < ends, 1, -1))):
        raise ValueError(f"{label}: a closed surface cannot be oriented consistently (non-orientable or "
                         f"self-touching); expected watertight, orientable surfaces")
    return tris


def _edge_keys(starts: np.ndarray, ends: np.ndarray, n_points: int) -> np.ndarray:
    """One int64 per undirected edge ``{start, end}``, equal for both directions."""
    lo, hi = np.minimum(starts, ends).astype(np.int64), np.maximum(starts, ends).astype(np.int64)
    return lo * n_points + hi


# --- sampling ---------------------------------------------------------------------------------


def _sample_class(parts: list, mu: float, s: float):
    """Points ``(n, 3)`` mm, weights ``(n,)`` mm² and the longest edge between neighbouring points
    (mm; None when there are none) of one class's parts ``[(points, triangles, label)]``."""
    if not parts:
        return np.zeros((0, 3)), np.zeros(0), None
    volumes = np.array([_signed_volume(p, t) for p, t, _ in parts])
    for (p, t, label), v in zip(parts, volumes):
        if abs(v) <= 1e-9 * _area(p, t).sum() ** 1.5:
            raise ValueError(f"{label}: a closed surface encloses no volume ({v:.3g} mm³); expected solids")
    group = _cavity_parents(parts, np.abs(volumes))
    solid_volume = np.zeros(len(parts))
    np.add.at(solid_volume, group, np.where(group == np.arange(len(parts)), 1.0, -1.0) * np.abs(volumes))
    samples = [_vertex_samples(p, t, EDGE_OVER_SPACING * s) for p, t, _ in parts]
    solid_area = np.zeros(len(parts))
    np.add.at(solid_area, group, [a.sum() for _, a, _ in samples])
    points = np.vstack([v for v, _, _ in samples])
    weights = np.concatenate([mu * solid_volume[group[i]] * a / solid_area[group[i]]
                              for i, (_, a, _) in enumerate(samples)])
    return points, weights, max(step for _, _, step in samples)


def _signed_volume(points: np.ndarray, triangles: np.ndarray) -> float:
    """Volume (mm³) of a closed, consistently oriented surface by the divergence theorem; positive
    for outward normals. Taken about one of its vertices: CAD frames may sit far from the origin."""
    p = points[triangles] - points[triangles[0, 0]]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6)


def _area(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p = points[triangles]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def _cavity_parents(parts: list, volumes: np.ndarray) -> np.ndarray:
    """Index of the solid each part belongs to: itself, or for a cavity (a surface inside an odd
    number of the class's other surfaces) the smallest surface containing it."""
    boxes = np.array([[p[np.unique(t)].min(0), p[np.unique(t)].max(0)] for p, t, _ in parts])
    group = np.arange(len(parts))
    for i, (p, t, _) in enumerate(parts):
        inside = [j for j in range(len(parts)) if j != i and np.all(boxes[j, 0] <= boxes[i, 0])
                  and np.all(boxes[i, 1] <= boxes[j, 1]) and _inside(p[t[0, 0]], parts[j][0][parts[j][1]])]
        if len(inside) % 2 == 1:
            group[i] = min(inside, key=lambda j: volumes[j])
    return group


def _inside(point: np.ndarray, corners: np.ndarray) -> bool:
    """Whether ``point`` is inside the closed surface of triangles ``corners`` ``(m, 3, 3)``: the
    parity of the crossings of a ray (Moller-Trumbore)."""
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    h = np.cross(_RAY, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-12
    f = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    sv = point - corners[:, 0]
    u = f * np.einsum("ij,ij->i", sv, h)
    q = np.cross(sv, e1)
    v = f * (q @ _RAY)
    t = f * np.einsum("ij,ij->i", e2, q)
    return bool(np.count_nonzero(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)) % 2)


def _vertex_samples(points: np.ndarray, triangles: np.ndarray, max_edge: float):
    """The vertices ``(n, 3)`` of the triangles bisected across their longest edge until no edge
    exceeds ``max_edge``, each with a third of the area of every piece it is a corner of
    (``(n,)`` mm², summing to the surface's area), and the longest edge left (mm)."""
    tri = points[triangles]  # (m, 3 corners, 3)
    pieces, longest_left = [], 0.0
    while len(tri):
        lengths = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)  # edge k runs from corner k to k + 1
        small = lengths.max(axis=1) <= max_edge
        pieces.append(tri[small])
        if small.any():
            longest_left = max(longest_left, float(lengths[small].max()))
        tri, k = tri[~small], lengths[~small].argmax(axis=1)
        # roll each triangle so that its longest edge runs from corner 0 to corner 1, then halve it
        rolled = tri[np.arange(len(tri))[:, None], (k[:, None] + np.arange(3)) % 3]
        mid = 0.5 * (rolled[:, 0] + rolled[:, 1])  # bit-identical from both sides of a shared edge
        tri = np.concatenate([np.stack([rolled[:, 0], mid, rolled[:, 2]], axis=1),
                              np.stack([mid, rolled[:, 1], rolled[:, 2]], axis=1)])
    corners = np.concatenate(pieces)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    vertices, index = _unique_rows(corners.reshape(-1, 3))
    vertex_area = np.bincount(index, weights=np.repeat(area / 3, 3), minlength=len(vertices))
    return vertices, vertex_area, longest_left


def _unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(unique rows, index of each row among them)`` for exactly equal float rows (-0.0 taken
    as 0.0); the rows' bytes compared at once rather than by ``np.unique(axis=0)``."""
    rows = np.ascontiguousarray(rows, dtype=np.float64) + 0.0
    keys = rows.view(np.dtype((np.void, rows.itemsize * rows.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return rows[first], inverse.reshape(-1)
