"""Tests of histostudy.pose.silhouette: the silhouette seed of the robust initialisation (beyond the
paper) on noise-free reference labels of a known pose, visible and mostly off the detectors."""

import numpy as np
import pytest

from histostudy.imaging import default_biplane, render_labels
from histostudy.learning import beam_direction_of_pose
from histostudy.pose.init import rotation_from_direction
from histostudy.pose.silhouette import silhouette_candidates, silhouette_seed
from histostudy.transducer import Feature, TransducerModel, pose_facing

T_TRUE = pose_facing((0.2, 1.0, -0.3), focal_point_mm=(22.0, -14.0, 9.0), axial_rotation_rad=0.6)

#: A pose with more than half of the transducer off both detectors (43 % of its points project
#: onto each).
T_HALF_HIDDEN = pose_facing((0.2, 1.0, -0.3), focal_point_mm=(22.0, -14.0, 70.0), axial_rotation_rad=0.6)


@pytest.fixture(scope="module")
def silhouettes():
    views = default_biplane()
    model = TransducerModel.build(spacing_mm=0.47)
    body = np.vstack([model.points[Feature.TRANSDUCER], model.points[Feature.OUTER_BOUNDARY]])
    body = body[np.random.default_rng(0).choice(len(body), 8000, replace=False)]
    masks = {name: [render_labels(model, T, v) > 0 for v in views]
             for name, T in (("visible", T_TRUE), ("half_hidden", T_HALF_HIDDEN))}
    return {"views": views, "body": body, "centre": body.mean(axis=0), "masks": masks}


def half_turn_difference_deg(a_deg, b_deg):
    return abs((a_deg - b_deg + 90.0) % 180.0 - 90.0)


@pytest.mark.parametrize("case, T, tolerance_mm", [("visible", T_TRUE, 5.0), ("half_hidden", T_HALF_HIDDEN, 10.0)])
def test_silhouette_seed_lands_near_the_true_translation(silhouettes, case, T, tolerance_mm):
    views, masks = silhouettes["views"], silhouettes["masks"][case]
    inside = [float(np.mean(m)) for m in masks]
    t, iou = silhouette_seed(T[:3, :3], views, masks, silhouettes["body"], centre_local_mm=silhouettes["centre"])
    assert np.linalg.norm(t - T[:3, 3]) < tolerance_mm, (case, t - T[:3, 3], inside)
    assert iou > 0.85
    # The visible part's centroid is not the transducer's: with most of it hidden, the rays
    # through the segmented centroids alone miss by centimetres, which the iteration corrects.
    if case == "half_hidden":
        once, _ = silhouette_seed(T[:3, :3], views, masks, silhouettes["body"], centre_local_mm=silhouettes["centre"],
                                  max_iter=0)
        assert np.linalg.norm(once - T[:3, 3]) > 3 * tolerance_mm


def test_silhouette_candidates_single_out_the_axial_angle_of_a_half_hidden_transducer(silhouettes):
    direction = beam_direction_of_pose(T_HALF_HIDDEN)
    found = silhouette_candidates(direction, silhouettes["views"], silhouettes["masks"]["half_hidden"],
                                  silhouettes["body"], centre_local_mm=silhouettes["centre"], keep=3)
    assert len(found) == 3 and [f[2] for f in found] == sorted((f[2] for f in found), reverse=True)
    angle, t, iou = found[0]
    true_deg = np.rad2deg(0.6)
    assert half_turn_difference_deg(angle, true_deg) <= 7.5 + 1e-9
    assert np.linalg.norm(t - T_HALF_HIDDEN[:3, 3]) < 15.0
    # 45 deg off the true axial angle, the best fitting translation lies centimetres away.
    R_wrong = rotation_from_direction(direction, np.deg2rad(true_deg + 45.0))
    t_wrong, iou_wrong = silhouette_seed(R_wrong, silhouettes["views"], silhouettes["masks"]["half_hidden"],
                                         silhouettes["body"], centre_local_mm=silhouettes["centre"])
    assert iou_wrong < iou - 0.1 and np.linalg.norm(t_wrong - T_HALF_HIDDEN[:3, 3]) > 20.0


def test_silhouette_seed_rejects_bad_input_and_returns_none_on_an_empty_view(silhouettes):
    views, masks = silhouettes["views"], silhouettes["masks"]["visible"]
    body, c = silhouettes["body"], silhouettes["centre"]
    R = T_TRUE[:3, :3]
    with pytest.raises(ValueError, match="two or more views"):
        silhouette_seed(R, views[:1], masks[:1], body, centre_local_mm=c)
    with pytest.raises(ValueError, match="mask shape"):
        silhouette_seed(R, views, [masks[0], masks[1][::2]], body, centre_local_mm=c)
    with pytest.raises(ValueError, match="axial_step_deg"):
        silhouette_candidates(beam_direction_of_pose(T_TRUE), views, masks, body, centre_local_mm=c, axial_step_deg=0)
    assert silhouette_seed(R, views, [masks[0], np.zeros_like(masks[1])], body, centre_local_mm=c) is None


def test_the_compiled_occupancy_is_numpys_cell_for_cell():
    # the one-pass kernel against numpy's formula (divide by w, keep the detector, floor to cells),
    # on points around and beyond a view, some behind the source
    from histostudy.pose.silhouette import _project_to_cells

    view = default_biplane()[0]
    rows, cols = view.shape
    rng = np.random.default_rng(3)
    world = rng.normal(0.0, 120.0, (5000, 3))
    world[:50] = view.source_mm + rng.normal(0.0, 10.0, (50, 3)) - 200.0 * (np.zeros(3) - view.source_mm) / 1000.0
    uvw = view.project_homogeneous(world)
    front = uvw[:, 2] > 0
    px = uvw[front, :2] / uvw[front, 2:3]
    inside = view.in_image(px)
    shape = (-(-rows // 16), -(-cols // 16))
    expected = np.zeros(shape, np.uint8)
    cells = np.floor((px[inside] + 0.5) / 16).astype(np.int64)
    expected[cells[:, 1], cells[:, 0]] = 1
    occupied, visible = _project_to_cells(uvw, rows, cols, 16, shape)
    assert 0 < inside.sum() < len(world) and not front.all()
    assert np.array_equal(occupied, expected)
    assert np.array_equal(world[visible], world[front][inside])
