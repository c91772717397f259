"""Tests of histostudy.pose.distance_maps: exact Euclidean distance maps per feature class (§II-B.3),
from label images and from masks, and their input validation."""

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from histostudy.imaging import View
from histostudy.pose import DistanceMaps
from histostudy.pose.distance_maps import euclidean_distance_map
from histostudy.transducer import Feature


def small_view(rows=60, cols=80):
    return View.from_gantry(0.0, 0.0, shape=(rows, cols), pixel_mm=4.0, name="small")


def test_distance_maps_equal_scipy_exact_edt():
    rng = np.random.default_rng(1)
    view = small_view(97, 131)
    mask = rng.random(view.shape) < 0.002
    mask[40:55, 60:90] = True  # a blob beside isolated pixels
    mask[0, 0] = True
    got = euclidean_distance_map(mask)
    assert got.dtype == np.float32
    # Exact: the float32 rounding of the true distance, bit for bit.
    np.testing.assert_array_equal(got, distance_transform_edt(~mask).astype(np.float32))
    # Also at the size of a detector and its largest distances (one pixel in a corner).
    big = np.zeros((960, 1240), bool)
    big[3, 5] = True
    np.testing.assert_array_equal(euclidean_distance_map(big), distance_transform_edt(~big).astype(np.float32))

    labels = np.zeros(view.shape, np.uint8)
    labels[mask] = int(Feature.GAPS)
    dm = DistanceMaps(view, labels)
    np.testing.assert_array_equal(dm.maps[Feature.GAPS], got)


def test_label_image_and_masks_agree_and_absent_classes_are_recorded():
    view = small_view()
    labels = np.zeros(view.shape, np.uint8)
    labels[10:20, 10:30] = int(Feature.TRANSDUCER)
    labels[30, 5:70] = int(Feature.OUTER_BOUNDARY)
    from_labels = DistanceMaps(view, labels)
    from_masks = DistanceMaps(view, {Feature.TRANSDUCER: labels == 1, Feature.OUTER_BOUNDARY: labels == 2,
                                     Feature.SCREWS: np.zeros(view.shape, bool)})
    for dm in (from_labels, from_masks):
        assert dm.present == (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY)
        assert dm.absent == (Feature.INNER_BOUNDARY, Feature.GAPS, Feature.SCREWS)
    for f in from_labels.present:
        np.testing.assert_array_equal(from_labels.maps[f], from_masks.maps[f])


def test_bad_segmentations_raise_clear_errors():
    view = small_view()
    with pytest.raises(ValueError, match=r"shape \(10, 10\).*\(60, 80\)"):
        DistanceMaps(view, np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match=r"segmentation\[GAPS\] has shape"):
        DistanceMaps(view, {Feature.GAPS: np.zeros((60, 81), bool)})
    with pytest.raises(ValueError, match=r"label values \[9\]"):
        DistanceMaps(view, np.full(view.shape, 9, np.uint8))
    with pytest.raises(ValueError, match="unknown class key"):
        DistanceMaps(view, {Feature.BACKGROUND: np.ones(view.shape, bool)})
