"""The parts of :func:`~histostudy.reporting.viz.targeting_scene` (§II-C, §II-D, Fig. 2): its input
checks, its content (:class:`_TargetingScene`), the drawing of each part and the two-panel off-screen
render. C-arm (CBCT, world) frame, LPS, mm; pyvista is imported inside the drawing helpers only."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from histostudy.geometry import check_rigid
from histostudy.transducer import FEATURE_CLASSES, Feature

__all__: list[str] = []

#: Colours of the C-arm planes in :func:`~histostudy.reporting.viz.targeting_scene` (plane A,
#: plane B, further views).
VIEW_COLOURS = ((0.85, 0.15, 0.15), (0.15, 0.35, 0.9), (0.2, 0.65, 0.3), (0.6, 0.3, 0.7))


def _optional_point(value, name: str) -> np.ndarray | None:
    """``value`` as 3 finite C-arm coordinates (mm), None for None; ``ValueError`` naming ``name``."""
    if value is None:
        return None
    p = np.asarray(value, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be 3 finite coordinates (C-arm frame, mm), got {value!r}")
    return p


def _detector_corners(view) -> np.ndarray:
    """``(4, 3)`` world corners of a view's detector (pixel edges), on the plane at the focal
    length ``K[0, 0] * pixel_mm`` from the source along the beam axis."""
    K, R, source = view.decomposition
    rows, cols = view.shape
    pixels = np.array([[-0.5, -0.5], [cols - 0.5, -0.5], [cols - 0.5, rows - 0.5], [-0.5, rows - 0.5]])
    rays = view.ray_directions(pixels)
    sdd = float(K[0, 0]) * view.pixel_mm
    return source + rays * (sdd / (rays @ R[2]))[:, None]


def _check_pairs(*, T_carm_base, joints_rad, model, T_carm_transducer, rng, zone_centre_mm, zone_radius_mm,
                 phantom_spec, T_carm_phantom) -> None:
    """Raise ``ValueError`` when half of an argument pair of the scene is given (robot: base
    transform and joints; transducer: model and pose, with an ``rng``; zone: centre and radius;
    phantom: spec needs its pose)."""
    if (T_carm_base is None) != (joints_rad is None):
        raise ValueError("T_carm_base and joints_rad go together (the robot is drawn with both, or not at all); "
                         f"got T_carm_base={'None' if T_carm_base is None else 'given'}, "
                         f"joints_rad={'None' if joints_rad is None else 'given'}")
    if (model is None) != (T_carm_transducer is None):
        raise ValueError("model and T_carm_transducer go together (the transducer is drawn with both, or not at all)")
    if model is not None and rng is None:
        raise ValueError("rng (numpy.random.Generator) is required to subsample the transducer model's points")
    if (zone_centre_mm is None) != (zone_radius_mm is None):
        raise ValueError("zone_centre_mm and zone_radius_mm go together")
    if phantom_spec is not None and T_carm_phantom is None:
        raise ValueError("phantom_spec needs T_carm_phantom (where the phantom is)")


def _checked_transforms(T_carm_base, joints_rad, T_carm_transducer, T_carm_phantom):
    """``(frames, T_ct, T_cp)``: the robot's DH frames in the C-arm frame (``(n, 4, 4)``, mm; from
    the base transform and the 6 UR5e joint angles in rad), the transducer's and the phantom's
    4x4 poses (C-arm <- part), each checked rigid; None where not given."""
    frames = None
    if T_carm_base is not None:
        from histostudy.robot.kinematics import check_joints, joint_frames

        T_cb = check_rigid(T_carm_base, "T_carm_base")
        frames = T_cb @ joint_frames(check_joints(joints_rad, "joints_rad"))
    T_ct = None if T_carm_transducer is None else check_rigid(T_carm_transducer, "T_carm_transducer")
    T_cp = None if T_carm_phantom is None else check_rigid(T_carm_phantom, "T_carm_phantom")
    return frames, T_ct, T_cp


def _checked_points(target_mm, zone_centre_mm, zone_radius_mm) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(target, zone_centre)`` as C-arm points (mm) or None, after checking the zone's radius
    (mm, finite and > 0 when given)."""
    target = _optional_point(target_mm, "target_mm")
    zone_centre = _optional_point(zone_centre_mm, "zone_centre_mm")
    if zone_radius_mm is not None and not (np.isfinite(zone_radius_mm) and zone_radius_mm > 0):
        raise ValueError(f"zone_radius_mm must be a finite radius > 0 in mm, got {zone_radius_mm!r}")
    return target, zone_centre


def _checked_render_options(window_size, camera_direction, max_points_per_class) -> tuple[int, int, np.ndarray]:
    """``(width, height, direction)``: the window in pixels (at least 16 x 16) and the camera's
    direction (a non-zero world 3-vector), after checking ``max_points_per_class >= 1``."""
    try:
        width, height = (int(v) for v in window_size)
    except (TypeError, ValueError):
        raise ValueError(f"window_size must be (width, height) in pixels, got {window_size!r}") from None
    if width < 16 or height < 16:
        raise ValueError(f"window_size must be at least (16, 16) pixels, got {window_size!r}")
    direction = np.asarray(camera_direction, dtype=np.float64).reshape(-1)
    if direction.shape != (3,) or not np.all(np.isfinite(direction)) or np.linalg.norm(direction) == 0:
        raise ValueError(f"camera_direction must be a non-zero 3-vector, got {camera_direction!r}")
    if int(max_points_per_class) < 1:
        raise ValueError(f"max_points_per_class must be >= 1, got {max_points_per_class!r}")
    return width, height, direction


def _transducer_points(model, T_ct: np.ndarray | None, rng: np.random.Generator | None,
                       max_points_per_class: int) -> dict:
    """``{class: (n, 3) C-arm mm}``: each class's model points in the pose ``T_ct`` (C-arm <-
    transducer), at most ``max_points_per_class`` drawn from ``rng`` (classes in
    :data:`FEATURE_CLASSES` order, empty classes left out); empty without a pose."""
    transducer_pts = {}
    if T_ct is not None:
        if rng is None:  # _check_pairs refuses a model without one first
            raise ValueError("rng (numpy.random.Generator) is required to subsample the transducer model's points")
        R, t = T_ct[:3, :3], T_ct[:3, 3]
        for k in FEATURE_CLASSES:
            pts = np.asarray(model.points[k])
            if len(pts) == 0:
                continue
            if len(pts) > max_points_per_class:
                pts = pts[rng.choice(len(pts), int(max_points_per_class), replace=False)]
            transducer_pts[k] = pts @ R.T + t
    return transducer_pts


@dataclass(frozen=True, eq=False)
class _TargetingScene:
    """What the targeting scene shows, checked, C-arm frame, mm: the ``views``; the robot's DH
    ``frames`` (or None); the transducer's pose ``T_ct``, its ``model``, its subsampled points per
    class with their RGB ``colours`` (0-1); the phantom's pose ``T_cp`` and half edge; the
    ``target`` and the zone's centre and radius (None where not shown)."""

    views: list
    frames: np.ndarray | None
    T_ct: np.ndarray | None
    model: Any  # a TransducerModel (its points, spec and focal point)
    transducer_pts: dict
    colours: dict
    T_cp: np.ndarray | None
    half_phantom: float | None
    target: np.ndarray | None
    zone_centre: np.ndarray | None
    zone_radius_mm: float | None


def _half_phantom(T_cp: np.ndarray | None, phantom_spec) -> float | None:
    """Half the phantom cube's edge (mm) of ``phantom_spec`` (default
    :class:`~histostudy.imaging.cbct.PhantomSpec`, §II-D.1); None without a phantom pose."""
    if T_cp is None:
        return None
    from histostudy.imaging import PhantomSpec

    return 0.5 * float((phantom_spec or PhantomSpec()).size_mm)


def _draw_views(plotter, views, label) -> None:
    """Each C-arm view (one colour per plane): its X-ray source as a sphere, its detector as a
    thin rectangle and the beam's frustum from the source to the detector corners (mm)."""
    import pyvista as pv

    for i, view in enumerate(views):
        colour = VIEW_COLOURS[i % len(VIEW_COLOURS)]
        source = view.source_mm
        corners = _detector_corners(view)
        name = f"plane {view.name}" if view.name else f"view {i}"
        plotter.add_mesh(pv.Sphere(radius=25.0, center=source), color=colour,
                         label=label(f"{name}: source, detector, beam"))
        plotter.add_mesh(pv.PolyData(corners, faces=np.array([4, 0, 1, 2, 3])), color=colour, opacity=0.45)
        plotter.add_mesh(pv.lines_from_points(np.vstack([corners, corners[:1]])), color=colour, line_width=3)
        apex = len(corners)
        frustum = pv.PolyData(np.vstack([corners, source]),
                              faces=np.hstack([[3, apex, k, (k + 1) % 4] for k in range(4)]))
        plotter.add_mesh(frustum, color=colour, opacity=0.07)
        for c in corners:
            plotter.add_mesh(pv.Line(source, c), color=colour, line_width=1.5, opacity=0.6)


def _draw_robot(plotter, frames: np.ndarray, label) -> None:
    """The UR5e as tubes between the origins of its DH ``frames`` (C-arm mm), spheres at its
    joints and the base as a disc (§II-C)."""
    import pyvista as pv

    joints = frames[:, :3, 3]
    plotter.add_mesh(pv.lines_from_points(joints).tube(radius=32.0, n_sides=20), color=(0.55, 0.58, 0.62),
                     label=label("UR5e (DH link chain)"))
    for p in joints[1:]:
        plotter.add_mesh(pv.Sphere(radius=42.0, center=p), color=(0.3, 0.45, 0.65))
    z_base = frames[0, :3, 2]
    plotter.add_mesh(pv.Cylinder(center=joints[0] + 10.0 * z_base, direction=z_base, radius=90.0,
                                 height=20.0), color=(0.25, 0.25, 0.3))


def _draw_transducer(plotter, scene: _TargetingScene, point_size: float, label) -> None:
    """The transducer's points coloured by class, its focal point as a red sphere with the axis
    to the cap's apex and, with the robot, the mount from the flange to the apex (C-arm mm)."""
    import pyvista as pv

    if scene.T_ct is None:
        return
    R, t = scene.T_ct[:3, :3], scene.T_ct[:3, 3]
    for k, pts in scene.transducer_pts.items():
        plotter.add_points(pts, color=scene.colours[k], point_size=point_size, render_points_as_spheres=False,
                           label=label("transducer") if k == Feature.TRANSDUCER else None)
    focal = R @ np.asarray(getattr(scene.model, "focal_point_mm", np.zeros(3)), float) + t
    plotter.add_mesh(pv.Sphere(radius=3.0, center=focal), color="red", label=label("focal point"))
    apex = R @ np.array([0.0, 0.0, scene.model.spec.radius_mm]) + t
    plotter.add_mesh(pv.Line(focal, apex), color="red", line_width=2)
    if scene.frames is not None:
        plotter.add_mesh(pv.Tube(pointa=scene.frames[-1, :3, 3], pointb=apex, radius=12.0), color=(0.4, 0.4, 0.4))


def _draw_scene(plotter, scene: _TargetingScene, point_size: float, legend: bool) -> None:
    """Every part of ``scene`` into the current panel: views, robot, transducer, phantom (a
    semi-transparent box with its edges), treated zone and target; with labels for the legend
    when ``legend``."""
    import pyvista as pv

    label = (lambda text: text) if legend else (lambda text: None)
    _draw_views(plotter, scene.views, label)
    if scene.frames is not None:
        _draw_robot(plotter, scene.frames, label)
    if scene.T_ct is not None:
        _draw_transducer(plotter, scene, point_size, label)
    if scene.T_cp is not None and scene.half_phantom is not None:  # set together (_half_phantom)
        h = scene.half_phantom
        box = pv.Box(bounds=(-h, h, -h, h, -h, h)).transform(scene.T_cp, inplace=False)
        plotter.add_mesh(box, color=(0.85, 0.7, 0.45), opacity=0.35, label=label("phantom"))
        plotter.add_mesh(box.extract_feature_edges(), color=(0.55, 0.4, 0.2), line_width=2)
    if scene.zone_centre is not None and scene.zone_radius_mm is not None:  # given together (checked)
        plotter.add_mesh(pv.Sphere(radius=float(scene.zone_radius_mm), center=scene.zone_centre),
                         color=(0.0, 0.75, 0.8), opacity=0.5, label=label("treated zone"))
    if scene.target is not None:
        plotter.add_mesh(pv.Sphere(radius=2.0, center=scene.target), color=(0.1, 0.8, 0.1), label=label("target"))


def _aim(plotter, direction: np.ndarray, bounds=None) -> None:
    """Point the current panel's camera at its scene (or at ``bounds``, world mm) from
    ``direction`` (world vector towards the camera), anterior (world -y) up."""
    plotter.reset_camera(bounds=bounds)
    focus = np.asarray(plotter.camera.focal_point)
    distance = plotter.camera.distance
    plotter.camera.position = tuple(focus + distance * direction / np.linalg.norm(direction))
    plotter.camera.focal_point = tuple(focus)
    plotter.camera.up = (0.0, -1.0, 0.0)
    plotter.reset_camera(bounds=bounds)


def _close_up_points(scene: _TargetingScene) -> list[np.ndarray]:
    """What the close-up frames (C-arm mm point sets): the target, the zone's centre, the
    phantom's extent along its diagonal and the transducer's points (its origin without any)."""
    near = [np.atleast_2d(v) for v in (scene.target, scene.zone_centre) if v is not None]
    if scene.T_cp is not None:
        near.append(scene.T_cp[:3, 3][None] + np.array([[-1.0], [1.0]]) * scene.half_phantom)
    if scene.T_ct is not None:
        near.append(np.vstack(list(scene.transducer_pts.values()) or [scene.T_ct[:3, 3][None]]))
    return near


def _render(scene: _TargetingScene, *, width: int, height: int, direction: np.ndarray, zoom: float, close_up: bool,
            point_size: float) -> np.ndarray:
    """Render ``scene`` off-screen, RGB uint8 ``(height, width, 3)``: the whole scene from
    ``direction`` zoomed by ``zoom`` and, with ``close_up`` and something near the focal point,
    a second panel framed on it (10 mm margin)."""
    import pyvista as pv

    near = _close_up_points(scene)
    panels = 2 if close_up and near else 1
    plotter = pv.Plotter(off_screen=True, window_size=[width, height], shape=(1, panels), border=False)
    plotter.set_background("white")  # type: ignore[arg-type]  # pyvista's decorated method types
    plotter.subplot(0, 0)
    _draw_scene(plotter, scene, point_size, legend=True)
    plotter.add_legend(bcolor="white", face="circle", size=(0.3 if panels == 2 else 0.24, 0.26),  # type: ignore[call-arg]
                       loc="lower right")
    plotter.add_axes(xlabel="x (L)", ylabel="y (P)", zlabel="z (S)")  # type: ignore[call-arg]  # pyvista's types
    _aim(plotter, direction)
    if zoom != 1.0:
        plotter.camera.zoom(float(zoom))
    if panels == 2:
        plotter.subplot(0, 1)
        _draw_scene(plotter, scene, point_size, legend=False)
        pts = np.vstack(near)
        lo, hi = pts.min(axis=0) - 10.0, pts.max(axis=0) + 10.0
        _aim(plotter, direction, bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        plotter.camera.zoom(1.2)
        plotter.add_text("close-up: transducer, phantom, target", position="upper_left", font_size=10, color="black")
    image = plotter.screenshot(return_img=True)
    plotter.close()
    return np.asarray(image, dtype=np.uint8)
