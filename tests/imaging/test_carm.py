"""Tests of histostudy.imaging.carm: the projection against an independent pinhole computation."""

import json

import numpy as np
import pytest

from histostudy.geometry import make_transform, rotation_about_axis, transform_points
from histostudy.imaging import View, default_biplane, load_views, save_views


def pinhole_pixel(point, primary_deg, secondary_deg, sod=785.0, sdd=1200.0, shape=(960, 1240), pixel=0.308):
    """Independent reference: intersect the source->point ray with the detector plane.

    Built from the gantry description alone (source opposite the detector on a sphere of radius
    SOD around the isocentre), not from any projection matrix.
    """
    a, b = np.deg2rad(primary_deg), np.deg2rad(secondary_deg)
    to_detector = np.array([np.sin(a) * np.cos(b), -np.cos(a) * np.cos(b), np.sin(b)])
    source = -sod * to_detector
    det_centre = source + sdd * to_detector
    # Detector axes: rows towards the feet, columns completing a right-handed (u, v, beam) frame.
    down = np.array([0.0, 0.0, -1.0])
    e_v = down - down.dot(to_detector) * to_detector
    e_v /= np.linalg.norm(e_v)
    e_u = np.cross(e_v, to_detector)
    ray = np.asarray(point, float) - source
    s = (det_centre - source).dot(to_detector) / ray.dot(to_detector)
    hit = source + s * ray
    rows, cols = shape
    return np.array([(hit - det_centre).dot(e_u) / pixel + (cols - 1) / 2,
                     (hit - det_centre).dot(e_v) / pixel + (rows - 1) / 2])


@pytest.mark.parametrize("primary, secondary", [(-45, 0), (45, 0), (0, 0), (30, 20), (-60, -25), (90, 0)])
def test_projection_matches_independent_pinhole(primary, secondary):
    view = View.from_gantry(primary, secondary)
    rng = np.random.default_rng(1)
    points = rng.uniform(-80, 80, size=(20, 3))
    expected = np.array([pinhole_pixel(p, primary, secondary) for p in points])
    assert np.allclose(view.project(points), expected, atol=1e-8)


def test_focal_point_of_a_known_pose_projects_where_the_pinhole_puts_it():
    view_a, view_b = default_biplane()
    # transducer above the patient, tilted, focal point 12 mm left, 5 mm anterior, 20 mm cranial
    T_carm_transducer = make_transform(rotation_about_axis([1, 0.3, 0], 1.9), [12.0, -5.0, 20.0])
    focal_world = transform_points(T_carm_transducer, [0.0, 0.0, 0.0])[0]
    assert np.allclose(view_a.project(focal_world)[0], pinhole_pixel(focal_world, -45, 0), atol=1e-8)
    assert np.allclose(view_b.project(focal_world)[0], pinhole_pixel(focal_world, 45, 0), atol=1e-8)


def test_isocentre_projects_to_detector_centre():
    for view in default_biplane():
        rows, cols = view.shape
        assert np.allclose(view.project([0, 0, 0])[0], [(cols - 1) / 2, (rows - 1) / 2], atol=1e-9)
    offset = View.from_gantry(10, 5, principal_point=(600.0, 500.0))
    assert np.allclose(offset.project([0, 0, 0])[0], [600.0, 500.0])


def test_default_biplane_is_the_papers_setup():
    a, b = default_biplane()
    assert (a.name, b.name) == ("A", "B")
    assert a.shape == (960, 1240) and a.pixel_mm == pytest.approx(0.308)
    assert a.gantry["primary_deg"] == -45 and b.gantry["primary_deg"] == 45
    # both sources 785 mm from the isocentre, 90 deg apart, posterior (under the table)
    assert np.linalg.norm(a.source_mm) == pytest.approx(785.0)
    assert np.dot(a.source_mm, b.source_mm) == pytest.approx(0.0, abs=1e-9)
    assert a.source_mm[1] > 0 and b.source_mm[1] > 0
    assert np.allclose(a.principal_direction, -a.source_mm / 785.0)
    assert a.scaled(0.25).shape == (240, 310)  # the paper's network input


def test_decomposition_recovers_intrinsics_and_axes():
    view = View.from_gantry(30, -10)
    K, R, C = view.decomposition
    assert np.allclose(K, [[1200 / 0.308, 0, 619.5], [0, 1200 / 0.308, 479.5], [0, 0, 1]])
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1)
    assert np.allclose(R[2], view.principal_direction)
    P = K @ np.hstack([R, -R @ C[:, None]])
    assert np.allclose(view.P / np.linalg.norm(view.P), P / np.linalg.norm(P))


def test_rays_pass_through_their_points():
    view = default_biplane()[0]
    pts = np.random.default_rng(2).uniform(-50, 50, (10, 3))
    d = view.ray_directions(view.project(pts))
    expected = (pts - view.source_mm) / np.linalg.norm(pts - view.source_mm, axis=1, keepdims=True)
    assert np.allclose(d, expected, atol=1e-10)


def test_pixel_footprint_is_the_magnified_pixel():
    view = View.from_gantry(0, 0)
    # on the principal ray at depth z from the source the footprint is (pixel * z / SID)^2
    for depth in (500.0, 785.0, 1000.0):
        point = view.source_mm + depth * view.principal_direction
        assert view.pixel_footprint_mm2(point)[0] == pytest.approx((0.308 * depth / 1200) ** 2)
    # scale invariance: P and 3P describe the same view
    scaled = View.from_matrix(3.0 * view.P, view.shape, view.pixel_mm)
    pts = np.random.default_rng(0).uniform(-60, 60, (5, 3))
    assert np.allclose(scaled.pixel_footprint_mm2(pts), view.pixel_footprint_mm2(pts))


def test_scaled_view_keeps_pixel_centres():
    view = default_biplane()[1]
    small = view.scaled(0.25)
    pts = np.random.default_rng(4).uniform(-60, 60, (10, 3))
    assert np.allclose(small.project(pts), 0.25 * view.project(pts) + (0.25 - 1) / 2)


def test_sign_of_P_is_normalised_so_w_is_positive_in_front():
    view = default_biplane()[0]
    flipped = View.from_matrix(-view.P, view.shape, view.pixel_mm)
    assert np.allclose(flipped.P, view.P)
    assert flipped.project_homogeneous([0, 0, 0])[0, 2] > 0


def test_in_image_uses_pixel_edges():
    view = View.from_gantry(0, 0, shape=(10, 20), pixel_mm=1.0)
    px = np.array([[-0.5, 0], [-0.51, 0], [19.49, 9.49], [19.5, 0], [0, 9.5]])
    assert view.in_image(px).tolist() == [True, False, True, False, False]


def test_views_round_trip_through_json(tmp_path):
    views = list(default_biplane()) + [View.from_matrix(default_biplane()[0].P * 2.5, (960, 1240), 0.308, name="user")]
    path = save_views(tmp_path / "views.json", views)
    loaded = load_views(path)
    assert [v.name for v in loaded] == ["A", "B", "user"]
    for v, w in zip(views, loaded):
        assert np.array_equal(v.P, w.P) and v.shape == w.shape and v.pixel_mm == w.pixel_mm
    assert loaded[0].gantry["primary_deg"] == -45 and loaded[2].gantry is None
    assert not list(tmp_path.glob("*.tmp*"))


def test_views_from_a_users_bare_matrix_list(tmp_path):
    P = default_biplane()[0].P.tolist()
    (tmp_path / "cal.json").write_text(
        json.dumps([{"name": "plane A", "P": P, "shape": [960, 1240], "pixel_mm": 0.308}]))
    (view,) = load_views(tmp_path / "cal.json")
    assert view.name == "plane A" and np.allclose(view.project([0, 0, 0]), [[619.5, 479.5]])
    (tmp_path / "bad.json").write_text(json.dumps([{"P": P, "shape": [960, 1240]}]))
    with pytest.raises(ValueError, match="pixel_mm"):
        load_views(tmp_path / "bad.json")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"P": np.zeros((3, 3)), "shape": (10, 10), "pixel_mm": 1.0}, "3x4"),
        ({"P": np.full((3, 4), np.inf), "shape": (10, 10), "pixel_mm": 1.0}, "finite"),
        ({"P": np.hstack([np.ones((3, 3)), np.ones((3, 1))]), "shape": (10, 10), "pixel_mm": 1.0}, "singular"),
        ({"P": np.hstack([np.eye(3), np.ones((3, 1))]), "shape": (0, 10), "pixel_mm": 1.0}, "shape"),
        ({"P": np.hstack([np.eye(3), np.ones((3, 1))]), "shape": (10, 10), "pixel_mm": -1.0}, "pixel_mm"),
    ],
)
def test_bad_views_are_rejected_with_the_argument_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        View(**kwargs)


def test_bad_gantry_parameters():
    with pytest.raises(ValueError, match="source_detector_mm"):
        View.from_gantry(0, 0, source_isocenter_mm=800, source_detector_mm=700)
    with pytest.raises(ValueError, match="primary_deg"):
        View.from_gantry(float("nan"))


def _xa_dataset(primary=30.0, secondary=-12.0, sod=785.0, sid=1200.0, spacing=(0.308, 0.308), shape=(96, 124)):
    from pydicom.dataset import Dataset

    ds = Dataset()
    ds.Modality = "XA"
    ds.PositionerPrimaryAngle, ds.PositionerSecondaryAngle = primary, secondary
    ds.DistanceSourceToPatient, ds.DistanceSourceToDetector = sod, sid
    ds.ImagerPixelSpacing = list(spacing)
    ds.Rows, ds.Columns = shape
    return ds


def _points(n=50):
    return np.random.default_rng(3).uniform(-60, 60, size=(n, 3))


def test_a_view_from_krt_projects_as_the_view_it_was_decomposed_from():
    view = View.from_gantry(25.0, -10.0, shape=(96, 124), pixel_mm=2.5)
    K, R, source = view.decomposition
    again = View.from_krt(K, R, -R @ source, view.shape, view.pixel_mm)
    np.testing.assert_allclose(again.project(_points()), view.project(_points()), atol=1e-9)
    with pytest.raises(ValueError, match="K must be upper triangular"):
        View.from_krt(K.T, R, -R @ source, view.shape, view.pixel_mm)
    with pytest.raises(ValueError, match="R"):
        View.from_krt(K, 2 * R, -R @ source, view.shape, view.pixel_mm)
    with pytest.raises(ValueError, match="t must be 3 finite"):
        View.from_krt(K, R, [0.0, np.nan, 1.0], view.shape, view.pixel_mm)


def test_a_view_from_dicom_xa_tags_is_the_gantry_view_of_the_same_angles():
    ds = _xa_dataset()
    view = View.from_dicom(ds, name="A")
    reference = View.from_gantry(30.0, -12.0, source_isocenter_mm=785.0, source_detector_mm=1200.0,
                                 shape=(96, 124), pixel_mm=0.308)
    np.testing.assert_allclose(view.project(_points()), reference.project(_points()), atol=1e-9)
    assert view.name == "A" and view.shape == (96, 124) and view.gantry["primary_deg"] == 30.0


def test_unequal_dicom_pixel_spacings_give_unequal_focal_lengths():
    view = View.from_dicom(_xa_dataset(spacing=(0.4, 0.2)))
    K, _, _ = view.decomposition
    assert K[0, 0] == pytest.approx(1200.0 / 0.2) and K[1, 1] == pytest.approx(1200.0 / 0.4)
    assert K[0, 2] == pytest.approx(61.5) and K[1, 2] == pytest.approx(47.5)  # the principal point stays


def test_an_enhanced_xa_object_gives_each_frame_its_own_angles(tmp_path):
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian

    ds = _xa_dataset()
    del ds.PositionerPrimaryAngle, ds.PositionerSecondaryAngle
    frames = []
    for primary in (-40.0, 45.0):
        position = Dataset()
        position.PositionerPrimaryAngle, position.PositionerSecondaryAngle = primary, 5.0
        group = Dataset()
        group.PositionerPositionSequence = [position]
        frames.append(group)
    ds.PerFrameFunctionalGroupsSequence = frames
    second = View.from_dicom(ds, frame_index=1)
    assert second.gantry["primary_deg"] == 45.0 and View.from_dicom(ds).gantry["primary_deg"] == -40.0
    with pytest.raises(ValueError, match=r"frame_index must be in \[0, 2\)"):
        View.from_dicom(ds, frame_index=2)
    ds.file_meta = FileMetaDataset()
    ds.file_meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds.SOPClassUID, ds.SOPInstanceUID = "1.2.840.10008.5.1.4.1.1.12.1.1", "1.2.3.4"
    ds.file_meta.MediaStorageSOPClassUID, ds.file_meta.MediaStorageSOPInstanceUID = ds.SOPClassUID, ds.SOPInstanceUID
    path = tmp_path / "xa.dcm"
    ds.save_as(path, enforce_file_format=True)
    np.testing.assert_allclose(View.from_dicom(path, frame_index=1).P, second.P)


@pytest.mark.parametrize("missing, tag", [("PositionerPrimaryAngle", r"\(0018,1510\)"),
                                          ("DistanceSourceToPatient", r"\(0018,1111\)"),
                                          ("ImagerPixelSpacing", r"\(0018,1164\)")])
def test_a_dicom_object_without_the_geometry_is_refused_naming_the_tag(missing, tag):
    ds = _xa_dataset()
    delattr(ds, missing)
    with pytest.raises(ValueError, match=rf"lacks {missing} {tag}"):
        View.from_dicom(ds)


def test_rotational_acquisitions_and_bad_values_are_refused():
    ds = _xa_dataset()
    ds.PositionerPrimaryAngleIncrement = [0.0, 1.0]
    with pytest.raises(ValueError, match="rotational acquisition"):
        View.from_dicom(ds)
    with pytest.raises(ValueError, match="DistanceSourceToDetector"):
        View.from_dicom(_xa_dataset(sid=700.0))  # closer than the isocentre
    with pytest.raises(ValueError, match="ImagerPixelSpacing"):
        View.from_dicom(_xa_dataset(spacing=(0.0, 0.3)))
