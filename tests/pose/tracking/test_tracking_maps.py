"""Tests of histostudy.pose.tracking._maps.RegionMaps: the same distance maps as DistanceMaps, in
buffers reused frame after frame; and of DistanceMaps.from_maps, which wraps them."""

import numpy as np
import pytest
from pose_frames import POSES

from histostudy.imaging import default_biplane, render_labels
from histostudy.pose import DistanceMaps
from histostudy.pose.tracking._maps import RegionMaps
from histostudy.pose.tracking._roi import crop_view
from histostudy.transducer import Feature, TransducerModel


@pytest.fixture(scope="module")
def labels_and_view():
    view = crop_view(default_biplane()[0], (64, 896, 96, 1152), 0.5)
    model = TransducerModel.build(spacing_mm=0.47)
    return render_labels(model, POSES[0], view), view


@pytest.mark.parametrize("occlusion_aware", [True, False])
def test_region_maps_equal_distance_maps(labels_and_view, occlusion_aware):
    labels, view = labels_and_view
    reference = DistanceMaps(view, labels, occlusion_aware=occlusion_aware)
    maps = RegionMaps(occlusion_aware=occlusion_aware).build(0, view, labels)
    assert maps.present == reference.present and maps.absent == reference.absent
    assert maps.occlusion_aware == occlusion_aware and maps.view is view
    for feature in reference.present:
        np.testing.assert_array_equal(maps.maps[feature], reference.maps[feature])


def test_a_region_over_1024_px_across_takes_the_float64_rounding_and_agrees():
    view = default_biplane()[0]  # 960 x 1240: diagonal 1568 px
    labels = np.zeros(view.shape, np.uint8)
    labels[5, 7] = int(Feature.TRANSDUCER)
    labels[900, 1200] = int(Feature.GAPS)
    maps = RegionMaps(occlusion_aware=True).build(0, view, labels)
    reference = DistanceMaps(view, labels, occlusion_aware=True)
    for feature in reference.present:
        np.testing.assert_array_equal(maps.maps[feature], reference.maps[feature])


def test_buffers_are_reused_while_the_shape_stays(labels_and_view):
    labels, view = labels_and_view
    builder = RegionMaps(occlusion_aware=True)
    first = builder.build(0, view, labels)
    array = first.maps[Feature.TRANSDUCER]
    shifted = np.roll(labels, 3, axis=1)
    second = builder.build(0, view, shifted)
    assert second.maps[Feature.TRANSDUCER] is array  # the same buffer, overwritten
    np.testing.assert_array_equal(array, DistanceMaps(view, shifted, occlusion_aware=True).maps[Feature.TRANSDUCER])
    builder.build(1, view, labels)  # another view: its own buffers
    assert builder.n_allocations == 2
    small = crop_view(default_biplane()[0], (64, 640, 96, 800), 0.5)
    builder.build(0, small, render_labels(TransducerModel.build(spacing_mm=0.47), POSES[0], small))
    assert builder.n_allocations == 3  # a new shape: new buffers


def test_bad_input_is_refused_naming_the_argument(labels_and_view):
    labels, view = labels_and_view
    builder = RegionMaps(occlusion_aware=True)
    with pytest.raises(ValueError, match="labels must be a uint8 label image"):
        builder.build(0, view, labels.astype(np.int32))
    with pytest.raises(ValueError, match="labels must be a uint8 label image"):
        builder.build(0, view, labels[:-1])
    bad = labels.copy()
    bad[0, 0] = 9
    with pytest.raises(ValueError, match=r"labels hold values \[9\]"):
        builder.build(0, view, bad)
    with pytest.raises(ValueError, match="occlusion_aware must be True or False"):
        RegionMaps(occlusion_aware="yes")
    with pytest.raises(ValueError, match=r"maps\[TRANSDUCER\] must be a float32 array"):
        DistanceMaps.from_maps(view, {Feature.TRANSDUCER: np.zeros(view.shape)}, occlusion_aware=True)
    with pytest.raises(ValueError, match="unknown class key"):
        DistanceMaps.from_maps(view, {0: np.zeros(view.shape, np.float32)}, occlusion_aware=True)


@pytest.mark.parametrize("occlusion_aware", [True, False])
@pytest.mark.parametrize("reach_px", [0.5, 1.0, 7.3, 15.0, 40.0])
def test_maps_cut_at_a_reach_are_exact_up_to_it_and_hold_it_beyond(labels_and_view, occlusion_aware, reach_px):
    labels, view = labels_and_view
    labels = labels.copy()
    labels[:40, :60] = int(Feature.SCREWS)  # a far blob: some pixels lie beyond every reach from it
    reference = DistanceMaps(view, labels, occlusion_aware=occlusion_aware)
    maps = RegionMaps(occlusion_aware=occlusion_aware).build(0, view, labels, reach_px=reach_px)
    assert maps.present == reference.present
    for feature in reference.present:
        exact = reference.maps[feature]
        assert (exact > reach_px).any() and (exact <= reach_px).any()
        np.testing.assert_array_equal(maps.maps[feature], np.minimum(exact, np.float32(reach_px)))


def test_costs_capped_within_the_reach_read_the_exact_maps_bits(labels_and_view):
    from histostudy.pose import PoseCost

    labels, view = labels_and_view
    model = TransducerModel.build(spacing_mm=0.47)
    exact = PoseCost(model.points, [DistanceMaps(view, labels, occlusion_aware=True)])
    cut = PoseCost(model.points, [RegionMaps(occlusion_aware=True).build(0, view, labels, reach_px=15.0)])
    T = POSES[0].copy()
    T[:3, 3] += [1.5, -2.0, 0.7]  # off the pose, so that the points meet every distance
    for cap in (0.5, 5.0, 15.0):
        a, b = exact.capped(cap), cut.capped(cap)
        assert a(T) == b(T)
        ne_a, ne_b = a.normal_equations(T), b.normal_equations(T)
        assert ne_a.cost == ne_b.cost and np.array_equal(ne_a.JtJ, ne_b.JtJ) and np.array_equal(ne_a.Jtr, ne_b.Jtr)
    far = POSES[0].copy()
    far[:3, 3] += [12.0, -9.0, 4.0]  # points 20-40 px off their class: beyond the reach the maps differ
    assert exact.capped(40.0)(far) != cut.capped(40.0)(far)
    assert exact.capped(15.0)(far) == cut.capped(15.0)(far)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), float("nan"), True, "15"])
def test_a_bad_reach_is_refused(labels_and_view, bad):
    labels, view = labels_and_view
    with pytest.raises(ValueError, match="reach_px"):
        RegionMaps(occlusion_aware=True).build(0, view, labels, reach_px=bad)
