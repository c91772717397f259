"""Tests of histostudy.treatment.plan: the focal points filling the zone and their order (§II-D)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from treatment_setup import R_CT, sphere_samples

from histostudy.treatment import TreatmentZone, plan_treatment


@pytest.mark.parametrize("diameter, spacing", [(20.0, 2.0), (25.0, 3.0), (20.0, 4.0)])
def test_plan_points_inside_on_the_lattice_and_covering_the_sphere(diameter, spacing):
    zone = TreatmentZone([1.0, -2.0, 3.0], diameter)
    plan = plan_treatment(zone, spacing, pulses_per_point=20, axes=R_CT)
    rel = plan.points_mm - zone.centre_mm
    assert np.all(np.linalg.norm(rel, axis=1) <= zone.radius_mm + 1e-9)
    # the lattice points sit at integer multiples of the spacing along the plan's axes ...
    lat = plan.points_mm[~plan.on_rim]
    coords = (lat - zone.centre_mm) @ R_CT / spacing
    assert np.allclose(coords, np.round(coords), atol=1e-9)
    assert np.array_equal(np.round(coords).astype(int), plan.lattice_index[~plan.on_rim])
    # ... with the requested spacing between nearest neighbours
    d, _ = cKDTree(lat).query(lat, k=2)
    assert np.allclose(d[:, 1], spacing)
    # rim points lie on the sphere
    assert np.allclose(np.linalg.norm(plan.points_mm[plan.on_rim] - zone.centre_mm, axis=1), zone.radius_mm)
    # every point of the sphere is within spacing * sqrt(3) / 2 of a focal point
    dist, _ = cKDTree(plan.points_mm).query(sphere_samples(zone.centre_mm, zone.radius_mm))
    assert np.isclose(plan.covering_radius_mm, spacing * np.sqrt(3) / 2)
    assert dist.max() <= plan.covering_radius_mm + 1e-9
    assert plan.pulses_per_point == 20 and len(np.unique(plan.points_mm, axis=0)) == len(plan)


def test_plan_with_inset_fills_the_inner_ellipsoid_with_anisotropic_spacing():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    inset = np.array([1.5, 1.5, 3.0])
    plan = plan_treatment(zone, (1.5, 2.0, 3.0), pulses_per_point=5, axes=R_CT, inset_mm=inset)
    semi = zone.radius_mm - inset
    local = plan.points_mm @ R_CT
    assert np.all(np.sum((local / semi) ** 2, axis=1) <= 1 + 1e-9)
    assert np.allclose(np.sum((local[plan.on_rim] / semi) ** 2, axis=1), 1.0, atol=1e-9)
    # coverage of the ellipsoid: sample it and check the covering radius |spacing| / 2
    g = sphere_samples(np.zeros(3), 1.0, step=0.05) * semi  # unit ball scaled to the ellipsoid
    dist, _ = cKDTree(local).query(g)
    assert dist.max() <= 0.5 * np.linalg.norm([1.5, 2.0, 3.0]) + 1e-9


def test_plan_order_is_deep_first_and_serpentine():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    plan = plan_treatment(zone, 2.0, axes=R_CT)
    ijk = plan.lattice_index
    assert np.all(np.diff(ijk[:, 2]) >= 0)  # layer by layer along the transducer's +z: deepest first
    depth_coord = plan.points_mm @ R_CT[:, 2]
    layer_means = [depth_coord[ijk[:, 2] == k].mean() for k in np.unique(ijk[:, 2])]
    assert np.all(np.diff(layer_means) > 1.0)  # along +z of the transducer: from the deepest layer up
    assert np.argmin(layer_means) == 0 and len(layer_means) == 11
    # rows: consecutive points in a row are lattice neighbours, and rows alternate direction
    same_row = (np.diff(ijk[:, 2]) == 0) & (np.diff(ijk[:, 1]) == 0)
    steps = np.diff(ijk[:, 0])[same_row]
    assert np.all(np.abs(steps) == 1)
    row_id = np.concatenate([[0], np.cumsum(~same_row)])
    # the r-th row (counting one-point rows too) runs along +x for even r, along -x for odd r
    for r in np.unique(row_id):
        if np.sum(row_id == r) > 1:
            assert np.sign(np.diff(ijk[row_id == r, 0])[0]) == (1 if r % 2 == 0 else -1)
    # a serpentine path is short: no jump longer than a few spacings
    assert np.linalg.norm(np.diff(plan.points_mm, axis=0), axis=1).max() < 4 * 2.0 * np.sqrt(3)


def test_plan_rejects_bad_parameters():
    zone = TreatmentZone([0.0, 0.0, 0.0], 20.0)
    for bad in (0.0, -1.0, (1.0, 0.0, 1.0)):
        with pytest.raises(ValueError, match="spacing_mm"):
            plan_treatment(zone, bad)
    with pytest.raises(ValueError, match="pulses_per_point"):
        plan_treatment(zone, 2.0, pulses_per_point=0)
    with pytest.raises(ValueError, match="inset_mm"):
        plan_treatment(zone, 2.0, inset_mm=(1.0, 1.0, 10.0))
    with pytest.raises(TypeError, match="TreatmentZone"):
        plan_treatment([0, 0, 0], 2.0)
