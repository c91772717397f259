"""Tests of histostudy.transducer.mesh and mesh_export: a TransducerModel sampled from closed CAD
meshes (TransducerModel.from_meshes) and the parametric model written as such meshes (§II-B.1)."""

import os

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

from scipy.spatial import cKDTree  # noqa: E402

from histostudy.core.io import process_umask  # noqa: E402
from histostudy.geometry import make_transform, rotation_about_axis  # noqa: E402
from histostudy.transducer import (  # noqa: E402
    FEATURE_CLASSES,
    Feature,
    TransducerModel,
    TransducerSpec,
    export_meshes,
)
from histostudy.transducer.mesh import default_mesh_mu_per_mm  # noqa: E402

S = 0.47  # the paper's pose-estimation spacing (mm)


def box(half=(20.0, 15.0, 10.0), centre=(0.0, 0.0, 0.0)):
    """A closed box (quads, 4 subdivisions a side) of half-widths ``half`` mm around ``centre``."""
    h, c = np.asarray(half), np.asarray(centre)
    return pv.Box(bounds=np.column_stack([c - h, c + h]).ravel(), level=4)


def polygon_cylinder(radius=10.0, height=40.0, n=64):
    """A closed n-sided cylinder along z and its exact volume (the prism's)."""
    mesh = pv.Cylinder(radius=radius, height=height, direction=(0, 0, 1), resolution=n, capping=True)
    return mesh, 0.5 * n * radius ** 2 * np.sin(2 * np.pi / n) * height


def as_single_mesh(parts):
    """One PolyData of ``{class value or name: mesh}`` with the cell array ``feature``."""
    blocks = []
    for value, mesh in parts.items():
        mesh = mesh.triangulate()
        mesh.cell_data["feature"] = np.full(mesh.n_cells, value)
        blocks.append(mesh)
    return pv.merge(blocks)


# --- known ground truth: solids of known volume --------------------------------------------------


def test_a_cylinder_weighs_mu_times_its_volume_and_its_points_lie_on_its_surface():
    mesh, volume = polygon_cylinder()
    model = TransducerModel.from_meshes({"screws": mesh}, spacing_mm=S)
    pts, w = model.points[Feature.SCREWS], model.weights[Feature.SCREWS]
    mu = default_mesh_mu_per_mm()[Feature.SCREWS]
    assert w.sum() == pytest.approx(mu * volume, rel=1e-6)  # pyvista stores float32 points
    assert w.sum() == pytest.approx(mu * np.pi * 10.0 ** 2 * 40.0, rel=2e-3)  # the tessellation's error
    tol = 1e-5  # float32 points
    on_cap = np.isclose(np.abs(pts[:, 2]), 20.0, atol=tol)
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.all(on_cap | ((r <= 10.0 + tol) & (r >= 10.0 * np.cos(np.pi / 64) - tol)))
    assert np.all(r[on_cap] <= 10.0 + tol) and np.all(np.abs(pts[:, 2]) <= 20.0 + tol)
    assert all(len(model.points[f]) == 0 for f in FEATURE_CLASSES if f != Feature.SCREWS)


def test_a_box_is_sampled_within_the_spacing_bound_with_weights_in_proportion_to_area():
    model = TransducerModel.from_meshes({Feature.TRANSDUCER: box()}, spacing_mm=S, mu_per_mm={"transducer": 1.0})
    pts, w = model.points[Feature.TRANSDUCER], model.weights[Feature.TRANSDUCER]
    assert w.sum() == pytest.approx(40 * 30 * 20, rel=1e-9)  # mu 1/mm x volume mm³
    # every point on a face of the box
    scaled = np.abs(pts) / [20.0, 15.0, 10.0]
    np.testing.assert_allclose(scaled.max(axis=1), 1.0, atol=1e-12)
    # no edge longer than 2 spacings, so no point farther than that from its neighbour
    assert 0 < model.grid_step_mm[Feature.TRANSDUCER] <= 2 * S
    nearest = cKDTree(pts).query(pts, k=2)[0][:, 1]
    assert nearest.max() <= 2 * S + 1e-9
    # the +x face (30 x 20 mm of the 5200 mm² surface) carries its share of the weight: more than
    # the points inside it, less than those with its edges (shared with the next faces)
    on_face = np.isclose(pts[:, 0], 20.0)
    inside = on_face & (np.abs(pts[:, 1]) < 15 - 1e-9) & (np.abs(pts[:, 2]) < 10 - 1e-9)
    assert w[inside].sum() < 24000 * 600 / 5200 < w[on_face].sum()
    assert w[on_face].sum() - w[inside].sum() < 0.1 * w[on_face].sum()
    # at least a point per (2 spacings)² of surface, not a swarm
    assert 5200 / (2 * S) ** 2 <= len(pts) <= 5200 / (S / 2) ** 2


def test_sampling_is_deterministic_and_the_cavity_of_a_hollow_solid_is_taken_out():
    hollow = pv.merge([box((20.0, 20.0, 20.0)), box((10.0, 10.0, 10.0))])  # a box with a box-shaped cavity
    a = TransducerModel.from_meshes({"transducer": hollow}, mu_per_mm={"transducer": 1.0})
    b = TransducerModel.from_meshes({"transducer": hollow}, mu_per_mm={"transducer": 1.0})
    np.testing.assert_array_equal(a.points[Feature.TRANSDUCER], b.points[Feature.TRANSDUCER])
    np.testing.assert_array_equal(a.weights[Feature.TRANSDUCER], b.weights[Feature.TRANSDUCER])
    assert a.weights[Feature.TRANSDUCER].sum() == pytest.approx(40 ** 3 - 20 ** 3, rel=1e-9)
    # two separate solids (the inner box moved out) add up instead
    apart = pv.merge([box((20.0, 20.0, 20.0)), box((10.0, 10.0, 10.0), centre=(60.0, 0, 0))])
    c = TransducerModel.from_meshes({"transducer": apart}, mu_per_mm={"transducer": 1.0})
    small = c.points[Feature.TRANSDUCER][:, 0] > 40
    assert c.weights[Feature.TRANSDUCER][small].sum() == pytest.approx(20 ** 3, rel=1e-9)  # each its own volume
    assert c.weights[Feature.TRANSDUCER][~small].sum() == pytest.approx(40 ** 3, rel=1e-9)


def test_a_surface_with_flipped_triangles_is_reoriented_before_its_volume_is_taken():
    sphere = pv.Sphere(radius=30.0, theta_resolution=40, phi_resolution=40)
    faces = sphere.faces.reshape(-1, 4).copy()
    faces[::3, 1:] = faces[::3, :0:-1]  # every third triangle turned over
    flipped = pv.PolyData(sphere.points, faces.ravel())
    volume = TransducerModel.from_meshes({"transducer": sphere}, mu_per_mm={"transducer": 1.0})
    again = TransducerModel.from_meshes({"transducer": flipped}, mu_per_mm={"transducer": 1.0})
    total = volume.weights[Feature.TRANSDUCER].sum()
    assert total == pytest.approx(4 / 3 * np.pi * 30 ** 3, rel=0.01)
    assert again.weights[Feature.TRANSDUCER].sum() == pytest.approx(total, rel=1e-9)


def test_classes_come_from_a_cell_array_of_values_or_names_in_a_file(tmp_path):
    cylinder, volume = polygon_cylinder(radius=3.0, height=8.0, n=32)
    parts = {int(Feature.SCREWS): cylinder.translate((0, 0, 60.0)), int(Feature.TRANSDUCER): box(),
             int(Feature.GAPS): box((2.0, 2.0, 2.0), centre=(40.0, 0, 0))}
    path = tmp_path / "transducer.vtp"
    as_single_mesh(parts).save(path)
    model = TransducerModel.from_meshes(path)
    mu = default_mesh_mu_per_mm()
    assert model.weights[Feature.SCREWS].sum() == pytest.approx(mu[Feature.SCREWS] * volume, rel=1e-6)
    assert model.weights[Feature.TRANSDUCER].sum() == pytest.approx(mu[Feature.TRANSDUCER] * 24000, rel=1e-9)
    assert len(model.points[Feature.GAPS]) > 0 and np.all(model.weights[Feature.GAPS] == 0)  # no material
    assert np.all(model.points[Feature.SCREWS][:, 2] >= 56.0 - 1e-9)
    named = TransducerModel.from_meshes(as_single_mesh({"Screws": cylinder.translate((0, 0, 60.0)),
                                                        "transducer": box()}))
    np.testing.assert_allclose(named.weights[Feature.SCREWS].sum(), model.weights[Feature.SCREWS].sum())


@pytest.mark.parametrize("units, mm_per_unit", [("m", 1000.0), ("cm", 10.0), ("in", 25.4)])
def test_units_convert_to_mm(units, mm_per_unit):
    reference = TransducerModel.from_meshes({"transducer": box()}, mu_per_mm={"transducer": 1.0})
    scaled = box(tuple(np.array([20.0, 15.0, 10.0]) / mm_per_unit))
    model = TransducerModel.from_meshes({"transducer": scaled}, units=units, mu_per_mm={"transducer": 1.0})
    assert model.weights[Feature.TRANSDUCER].sum() == pytest.approx(24000, rel=1e-6)  # float32 points
    assert np.abs(model.points[Feature.TRANSDUCER]).max(axis=0) == pytest.approx([20.0, 15.0, 10.0], rel=1e-6)
    assert len(model.points[Feature.TRANSDUCER]) == len(reference.points[Feature.TRANSDUCER])


def test_the_cad_frame_is_moved_into_the_transducer_frame_and_the_focal_point_kept():
    T = make_transform(rotation_about_axis([0, 0, 1], np.pi / 2), [1.0, 2.0, 3.0])
    plain = TransducerModel.from_meshes({"transducer": box()})
    moved = TransducerModel.from_meshes({"transducer": box()}, T_transducer_mesh=T, focal_point_mm=(0, 0, -2.0),
                                        spec=TransducerSpec(radius_mm=150.0))
    expected = plain.points[Feature.TRANSDUCER] @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(np.sort(moved.points[Feature.TRANSDUCER], axis=0), np.sort(expected, axis=0),
                               atol=1e-9)
    np.testing.assert_array_equal(moved.focal_point_mm, [0, 0, -2.0])
    assert moved.spec.radius_mm == 150.0 and plain.spec == TransducerSpec()


# --- bad input: each error names the file or key, the value and what was expected -----------------


def test_an_open_mesh_is_refused_with_its_count_of_open_edges(tmp_path):
    closed = box().triangulate()
    faces = closed.faces.reshape(-1, 4)[1:]  # one triangle taken out: three open edges
    path = tmp_path / "housing.stl"
    pv.PolyData(closed.points, faces.ravel()).save(path)
    with pytest.raises(ValueError, match=r"housing\.stl: 3 open edges .* in 1 of its 1 surfaces \(no closed\)"):
        TransducerModel.from_meshes({"outer_boundary": path})
    sheet = pv.Plane(i_size=50, j_size=50)
    with pytest.raises(ValueError, match=r"meshes\['gaps'\]: \d+ open edges"):
        TransducerModel.from_meshes({"transducer": box(), "gaps": sheet})


def test_an_empty_or_missing_mesh_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match=r"meshes\['screws'\]: the mesh is empty"):
        TransducerModel.from_meshes({"screws": pv.PolyData()})
    lines = pv.Line((0, 0, 0), (100, 0, 0))
    with pytest.raises(ValueError, match="empty"):
        TransducerModel.from_meshes({"screws": lines})
    missing = tmp_path / "screws.stl"
    with pytest.raises(FileNotFoundError, match=r"screws\.stl: mesh file not found"):
        TransducerModel.from_meshes({"screws": missing})
    with pytest.raises(ValueError, match=r"meshes is an empty mapping"):
        TransducerModel.from_meshes({})
    with pytest.raises(TypeError, match=r"meshes\['screws'\]: expected a mesh file path or a pyvista.PolyData, "
                                        r"got int"):
        TransducerModel.from_meshes({"screws": 3})


def test_unknown_classes_and_duplicate_keys_are_refused():
    with pytest.raises(ValueError, match=r"meshes key 'handle': unknown feature class 'handle'; expected one of "
                                         r"\['transducer', 'outer_boundary'"):
        TransducerModel.from_meshes({"handle": box()})
    with pytest.raises(ValueError, match=r"unknown feature class <Feature.BACKGROUND: 0>"):
        TransducerModel.from_meshes({Feature.BACKGROUND: box()})
    with pytest.raises(ValueError, match=r"both name SCREWS"):
        TransducerModel.from_meshes({"screws": box(), Feature.SCREWS: box()})
    with pytest.raises(ValueError, match=r"cell array 'feature': unknown feature class 9"):
        TransducerModel.from_meshes(as_single_mesh({9: box()}))
    with pytest.raises(ValueError, match=r"meshes: a single mesh needs a cell array 'feature'"):
        TransducerModel.from_meshes(box())
    two_classes = as_single_mesh({1: box()})
    two_classes.cell_data["feature"][:5] = 5
    with pytest.raises(ValueError, match=r"one closed surface carries the classes \['TRANSDUCER', 'SCREWS'\]"):
        TransducerModel.from_meshes(two_classes)


def test_a_mesh_in_metres_read_as_mm_is_refused_with_a_hint():
    metres = box((0.12, 0.085, 0.01))
    with pytest.raises(ValueError, match=r"span 0\.24 mm read as units='mm'.*pass units='m'"):
        TransducerModel.from_meshes({"transducer": metres})
    in_metres = TransducerModel.from_meshes({"transducer": metres}, units="m", spacing_mm=2.0)
    assert np.abs(in_metres.points[Feature.TRANSDUCER]).max() == pytest.approx(120.0, rel=1e-6)
    with pytest.raises(ValueError, match=r"units must be one of \['cm', 'in', 'm', 'mm'\], got 'km'"):
        TransducerModel.from_meshes({"transducer": box()}, units="km")


def test_non_finite_points_a_non_rigid_transform_and_bad_attenuations_are_refused():
    bad = box().triangulate()
    bad.points[3] = [np.nan, 0, 0]
    with pytest.raises(ValueError, match=r"meshes\['transducer'\]: 1 of its \d+ points are not finite"):
        TransducerModel.from_meshes({"transducer": bad})
    with pytest.raises(ValueError, match=r"T_transducer_mesh"):
        TransducerModel.from_meshes({"transducer": box()}, T_transducer_mesh=np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match=r"mu_per_mm\['gaps'\] must be 0: GAPS mark the absence of material"):
        TransducerModel.from_meshes({"transducer": box()}, mu_per_mm={"gaps": 0.3})
    with pytest.raises(ValueError, match=r"mu_per_mm\['screws'\] must be a finite attenuation >= 0"):
        TransducerModel.from_meshes({"transducer": box()}, mu_per_mm={"screws": -1.0})
    with pytest.raises(ValueError, match=r"focal_point_mm must be 3 finite numbers"):
        TransducerModel.from_meshes({"transducer": box()}, focal_point_mm=(0, np.inf, 0))
    with pytest.raises(ValueError, match=r"spacing_mm must be finite and > 0"):
        TransducerModel.from_meshes({"transducer": box()}, spacing_mm=0)


# --- the parametric model as meshes, and back ------------------------------------------------------


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The paper's parametric model at 0.47 mm, its meshes and the model read back from them."""
    folder = tmp_path_factory.mktemp("meshes")
    parametric = TransducerModel.build(spacing_mm=S)
    paths = export_meshes(parametric, folder)
    return parametric, paths, TransducerModel.from_meshes(paths, spacing_mm=S)


def test_export_writes_one_closed_mesh_per_class_atomically(exported):
    parametric, paths, _ = exported
    assert {f: p.name for f, p in paths.items()} == {f: f"{f.name.lower()}.stl" for f in FEATURE_CLASSES}
    folder = next(iter(paths.values())).parent
    assert sorted(os.listdir(folder)) == sorted(p.name for p in paths.values())  # no temporary file left
    for path in paths.values():
        assert os.stat(path).st_mode & 0o777 == 0o666 & ~process_umask()
        mesh = pv.read(path)
        assert mesh.n_cells > 0 and mesh.n_open_edges == 0


def test_the_meshes_hold_the_parametric_attenuation_per_class_and_comparable_point_counts(exported):
    parametric, _, model = exported
    for f in FEATURE_CLASSES:
        # mu x the exported volumes against the parametric sampling's sum of weights: independent sums
        assert model.weights[f].sum() == pytest.approx(parametric.weights[f].sum(), rel=0.02), f.name
    # a slab shows two faces where the parametric cap is one sheet: about twice the points; the
    # gaps' thin sheets and the screws' 48-sided surfaces more against a stripe and a volume grid
    limits = {Feature.TRANSDUCER: 2.5, Feature.OUTER_BOUNDARY: 3.0, Feature.INNER_BOUNDARY: 2.5,
              Feature.GAPS: 5.0, Feature.SCREWS: 7.0}
    for f, limit in limits.items():
        ratio = model.n_points[f] / parametric.n_points[f]
        assert 1.0 <= ratio <= limit, (f.name, ratio)
        assert model.grid_step_mm[f] <= 2 * S
    assert np.all(model.weights[Feature.GAPS] == 0)


def test_export_in_other_formats_reads_back_the_same_and_refuses_a_physical_model(tmp_path):
    spec = TransducerSpec(screw_count=0, outer_wall_height_mm=0.0)
    paths = export_meshes(spec, tmp_path, format="ply", max_edge_mm=4.0)
    assert sorted(p.name for p in paths.values()) == ["gaps.ply", "inner_boundary.ply", "outer_boundary.ply",
                                                      "transducer.ply"]
    model = TransducerModel.from_meshes(paths, spacing_mm=1.0, spec=spec)
    parametric = TransducerModel.build(spec, spacing_mm=1.0)
    for f in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY):
        assert model.weights[f].sum() == pytest.approx(parametric.weights[f].sum(), rel=0.02), f.name
    assert model.n_points[Feature.SCREWS] == 0
    physical = TransducerModel.build_physical(spacing_mm=1.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="physical model"):
        export_meshes(physical, tmp_path)
    with pytest.raises(ValueError, match=r"format must be one of"):
        export_meshes(spec, tmp_path, format="step")
    with pytest.raises(TypeError, match="model_or_spec must be a TransducerSpec or a TransducerModel"):
        export_meshes("spec.json", tmp_path)


@pytest.mark.slow
def test_the_model_read_back_from_its_meshes_finds_the_same_pose(exported):
    """The issue's round trip: the same biplane frames, the parametric model and the one read back
    from its meshes give focal points within 0.1 mm of each other.

    The labels come from the paper's 0.125 mm rendering model: at 0.25 mm the labelled gap stripes
    cover only |x| <= 0.5 of the 0.75 mm half-gap (the grid's points in it), which the parametric
    0.47 mm points fit but the meshes' true 1.5 mm gap does not (measured: 0.30 mm apart then, 0.2 mm
    of it from the gaps alone; 0.05 mm with these labels)."""
    from histostudy.imaging import default_biplane, random_background, render_frame
    from histostudy.learning import OracleOrientation, OracleSegmenter
    from histostudy.pose import estimate_pose
    from histostudy.transducer import pose_facing

    parametric, _, from_meshes = exported
    labels, image = TransducerModel.build(spacing_mm=0.125), TransducerModel.build(spacing_mm=0.25)
    T = pose_facing((0.15, 1.0, 0.25), focal_point_mm=(4.0, -6.0, 8.0), axial_rotation_rad=0.35)
    rng, scene = np.random.default_rng(1), random_background(np.random.default_rng(2), "phantom")
    frames = [render_frame(labels, T, view, rng=rng, physical=image, background=scene) for view in default_biplane()]
    focal = {}
    for name, model in (("parametric", parametric), ("meshes", from_meshes)):
        result = estimate_pose(frames, model, segmenter=OracleSegmenter(), orientation=OracleOrientation(),
                               rng=np.random.default_rng(0), mode="fast")
        focal[name] = result.focal_point_mm
        assert np.linalg.norm(result.focal_point_mm - T[:3, 3]) < 0.5, name
    assert np.linalg.norm(focal["parametric"] - focal["meshes"]) < 0.1
