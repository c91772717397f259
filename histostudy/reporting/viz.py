"""Figures the notebooks share: colour-coded label maps (Fig. 5 style) and 3-D scenes (pyvista).

Matplotlib figures are returned, never shown or saved here; the notebook records them through
:class:`histostudy.reporting.report.SectionWriter`. 3-D scenes render off-screen: on a machine without a
display VTK renders through EGL (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``), set here
before VTK loads when no ``DISPLAY`` is present.
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from histostudy.transducer import FEATURE_CLASSES, Feature

__all__ = ["FEATURE_COLOURS", "label_rgb", "model_scene", "plot_frames_with_labels", "plot_pose_overlay",
           "targeting_scene"]

#: RGB colours of the paper's Fig. 5: orange elements, blue outer boundary, purple inner boundary,
#: green gaps, yellow screws; background black.
FEATURE_COLOURS = {
    Feature.BACKGROUND: (0, 0, 0),
    Feature.TRANSDUCER: (245, 140, 30),
    Feature.OUTER_BOUNDARY: (40, 110, 240),
    Feature.INNER_BOUNDARY: (160, 60, 200),
    Feature.GAPS: (40, 190, 70),
    Feature.SCREWS: (250, 230, 40),
}

FEATURE_NAMES = {
    Feature.BACKGROUND: "background",
    Feature.TRANSDUCER: "transducer elements",
    Feature.OUTER_BOUNDARY: "outer boundary",
    Feature.INNER_BOUNDARY: "inner boundary",
    Feature.GAPS: "gaps",
    Feature.SCREWS: "screws",
}


def label_rgb(labels: np.ndarray) -> np.ndarray:
    """``(rows, cols, 3)`` uint8 colour image of a label map (colours of :data:`FEATURE_COLOURS`)."""
    labels = np.asarray(labels)
    lut = np.zeros((256, 3), np.uint8)
    for k, colour in FEATURE_COLOURS.items():
        lut[int(k)] = colour
    return lut[labels.astype(np.uint8)]


def _display_range(image: np.ndarray) -> tuple[float, float]:
    lo, hi = np.percentile(image, [1, 99.5])
    return float(lo), float(max(hi, lo + 1e-6))


def plot_frames_with_labels(frames: Sequence, predictions: Sequence[np.ndarray] | None = None, *,
                            titles: Sequence[str] | None = None, panel_inches: float = 3.6):
    """Fig. 5 A-C for each frame (one row per view): the X-ray image (line integrals, dark =
    attenuating), the reference labels, and the predicted labels (or, without predictions, the
    reference labels blended over the image)."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    n = len(frames)
    fig, axes = plt.subplots(n, 3, figsize=(3 * panel_inches * 1.3, n * panel_inches), squeeze=False)
    for i, frame in enumerate(frames):
        lo, hi = _display_range(frame.image)
        name = titles[i] if titles else f"plane {frame.view.name}"
        axes[i, 0].imshow(frame.image, cmap="gray_r", vmin=lo, vmax=hi)
        axes[i, 0].set_title(f"A) {name}: X-ray (line integrals)")
        ref = label_rgb(frame.labels) if frame.labels is not None else np.zeros((*frame.shape, 3), np.uint8)
        axes[i, 1].imshow(ref)
        axes[i, 1].set_title("B) reference labels")
        if predictions is not None:
            axes[i, 2].imshow(label_rgb(predictions[i]))
            axes[i, 2].set_title("C) segmentation")
        else:
            grey = np.clip((frame.image - lo) / (hi - lo), 0, 1)
            base = np.repeat((255 * (1 - grey))[..., None], 3, axis=2)
            mask = (frame.labels > 0)[..., None] if frame.labels is not None else False
            axes[i, 2].imshow(np.where(mask, 0.45 * base + 0.55 * ref, base).astype(np.uint8))
            axes[i, 2].set_title("C) labels over the image")
        for ax in axes[i]:
            ax.set_xticks([])
            ax.set_yticks([])
    handles = [Patch(color=np.array(FEATURE_COLOURS[k]) / 255, label=FEATURE_NAMES[k]) for k in FEATURE_CLASSES]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def plot_pose_overlay(frames: Sequence, model, T_carm_transducer, *, rng: np.random.Generator,
                      max_points_per_class: int = 4000, titles: Sequence[str] | None = None,
                      panel_inches: float = 3.6):
    """Fig. 6, columns 1-2, for each frame (one row per view): the X-ray image, and the image with
    the digital model's points projected in the estimated pose ``T_carm_transducer`` (coloured
    by class, a random subset of at most ``max_points_per_class`` per class drawn from ``rng``)
    and the projected focal point (red cross)."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    T = np.asarray(T_carm_transducer, dtype=np.float64)
    n = len(frames)
    fig, axes = plt.subplots(n, 2, figsize=(2 * panel_inches * 1.3, n * panel_inches), squeeze=False)
    for i, frame in enumerate(frames):
        lo, hi = _display_range(frame.image)
        name = titles[i] if titles else f"plane {frame.view.name}"
        for ax in axes[i]:
            ax.imshow(frame.image, cmap="gray_r", vmin=lo, vmax=hi)
            ax.set_xticks([])
            ax.set_yticks([])
        axes[i, 0].set_title(f"{name}: X-ray")
        axes[i, 1].set_title(f"{name}: model in the estimated pose")
        for k in FEATURE_CLASSES:
            pts = np.asarray(model.points[k])
            if len(pts) == 0:
                continue
            if len(pts) > max_points_per_class:
                pts = pts[rng.choice(len(pts), max_points_per_class, replace=False)]
            px = frame.view.project(pts @ T[:3, :3].T + T[:3, 3])
            axes[i, 1].scatter(px[:, 0], px[:, 1], s=0.3, color=np.array(FEATURE_COLOURS[k]) / 255, alpha=0.6,
                               linewidths=0)
        focal = frame.view.project(T[:3, :3] @ np.asarray(model.focal_point_mm, float) + T[:3, 3])[0]
        axes[i, 1].plot(*focal, "r+", markersize=12, markeredgewidth=2)
        rows, cols = frame.shape
        axes[i, 1].set_xlim(-0.5, cols - 0.5)
        axes[i, 1].set_ylim(rows - 0.5, -0.5)
    handles = [Line2D([], [], marker="o", linestyle="", color=np.array(FEATURE_COLOURS[k]) / 255,
                      label=FEATURE_NAMES[k]) for k in FEATURE_CLASSES]
    handles.append(Line2D([], [], marker="+", linestyle="", color="r", label="focal point"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def _prepare_offscreen() -> None:
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def model_scene(model, *, rng: np.random.Generator, max_points_per_class: int = 60000,
                window_size: tuple[int, int] = (1000, 760), point_size: float = 2.0,
                camera_elevation_deg: float = 35.0, camera_azimuth_deg: float = 30.0) -> np.ndarray:
    """Off-screen pyvista render of a transducer model's points coloured by class; RGB uint8.

    Each class is subsampled (``rng``) to ``max_points_per_class`` so a 0.125 mm model renders in
    about a second. The focal point is drawn as a red sphere, the axis as a line.
    """
    _prepare_offscreen()
    import pyvista as pv

    plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
    plotter.set_background("white")
    for k in FEATURE_CLASSES:
        pts = model.points[k]
        if len(pts) == 0:
            continue
        if len(pts) > max_points_per_class:
            pts = pts[rng.choice(len(pts), max_points_per_class, replace=False)]
        plotter.add_points(pts, color=np.array(FEATURE_COLOURS[k]) / 255, point_size=point_size,
                           render_points_as_spheres=False, label=FEATURE_NAMES[k])
    focal = np.asarray(getattr(model, "focal_point_mm", np.zeros(3)), float)
    plotter.add_mesh(pv.Sphere(radius=3.0, center=focal), color="red", label="focal point")
    apex = np.array([0.0, 0.0, model.spec.radius_mm])
    plotter.add_mesh(pv.Line(focal, apex), color="red", line_width=2)
    plotter.add_legend(bcolor="white", face="circle", size=(0.22, 0.22))
    plotter.camera_position = "xz"
    plotter.camera.elevation = camera_elevation_deg
    plotter.camera.azimuth = camera_azimuth_deg
    plotter.reset_camera()
    plotter.camera.zoom(1.3)
    image = plotter.screenshot(return_img=True)
    plotter.close()
    return np.asarray(image, dtype=np.uint8)


#: Colours of the C-arm planes in :func:`targeting_scene` (plane A, plane B, further views).
VIEW_COLOURS = ((0.85, 0.15, 0.15), (0.15, 0.35, 0.9), (0.2, 0.65, 0.3), (0.6, 0.3, 0.7))


def _optional_point(value, name: str) -> np.ndarray | None:
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


def targeting_scene(views, *, T_carm_base=None, joints_rad=None, model=None, T_carm_transducer=None,
                    rng: np.random.Generator | None = None, phantom_spec=None, T_carm_phantom=None,
                    target_mm=None, zone_centre_mm=None, zone_radius_mm=None,
                    window_size: tuple[int, int] = (1600, 800), max_points_per_class: int = 20000,
                    point_size: float = 2.0, camera_direction=(-0.55, -0.5, -1.0), zoom: float = 1.0,
                    close_up: bool = True) -> np.ndarray:
    """Off-screen pyvista render of the targeting set-up (§II-C, §II-D, Fig. 2); RGB uint8
    ``(rows, cols, 3)`` with ``(cols, rows) = window_size``.

    Everything is drawn in the C-arm (CBCT, world) frame, LPS, mm, anterior (world -y) up:

    - each view of ``views`` (:class:`~histostudy.imaging.carm.View`, e.g. :func:`~histostudy.imaging.carm.default_biplane`):
      the X-ray source as a sphere, the detector as a thin rectangle and the beam's frustum from the
      source to the detector corners (semi-transparent), one colour per plane;
    - with ``T_carm_base`` (4x4, C-arm <- robot base) and ``joints_rad`` (6 UR5e joint angles,
      rad): the arm as tubes between the origins of its DH frames
      (:func:`histostudy.robot.kinematics.joint_frames`), the base as a disc;
    - with ``model`` (:class:`~histostudy.transducer.TransducerModel`) and ``T_carm_transducer``
      (4x4, C-arm <- transducer): the model's points coloured by class (:data:`FEATURE_COLOURS`),
      at most ``max_points_per_class`` per class drawn from ``rng``, its focal point as a red sphere
      and, with the robot, the mount from the flange to the cap's apex;
    - with ``T_carm_phantom`` (4x4, C-arm <- phantom; the cube of ``phantom_spec``, default
      :class:`~histostudy.imaging.cbct.PhantomSpec`): the phantom as a semi-transparent box;
    - ``target_mm`` (3, C-arm mm) as a green sphere; ``zone_centre_mm`` with ``zone_radius_mm``
      (mm) as a semi-transparent cyan sphere (e.g. the segmented treated zone).

    The camera looks at the whole scene from ``camera_direction`` (world vector from the scene's
    centre towards the camera; default: from the patient's right, anterior and feet), then
    zooms by ``zoom``. With ``close_up`` (and a transducer, phantom, target or zone to show) the
    window is split: the whole scene on the left, on the right the same scene from the same
    direction framed on the transducer, the phantom, the target and the zone. About 2 s for the
    default window and 20000 points per class.

    Raises ``ValueError`` naming the argument for malformed input (a transform that is not 4x4
    rigid, not 6 joint angles, a point that is not 3 finite numbers, half of a pair given).
    """
    from histostudy.imaging.carm import views_from_sequence
    from histostudy.geometry import check_rigid

    seq = views_from_sequence(views)
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
    frames = None
    if T_carm_base is not None:
        from histostudy.robot.kinematics import check_joints, joint_frames

        T_cb = check_rigid(T_carm_base, "T_carm_base")
        frames = T_cb @ joint_frames(check_joints(joints_rad, "joints_rad"))
    T_ct = None if T_carm_transducer is None else check_rigid(T_carm_transducer, "T_carm_transducer")
    T_cp = None if T_carm_phantom is None else check_rigid(T_carm_phantom, "T_carm_phantom")
    target = _optional_point(target_mm, "target_mm")
    zone_centre = _optional_point(zone_centre_mm, "zone_centre_mm")
    if zone_radius_mm is not None and not (np.isfinite(zone_radius_mm) and zone_radius_mm > 0):
        raise ValueError(f"zone_radius_mm must be a finite radius > 0 in mm, got {zone_radius_mm!r}")
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

    _prepare_offscreen()
    import pyvista as pv

    half_phantom = None
    if T_cp is not None:
        from histostudy.imaging import PhantomSpec

        half_phantom = 0.5 * float((phantom_spec or PhantomSpec()).size_mm)
    transducer_pts = {}
    if T_ct is not None:
        R, t = T_ct[:3, :3], T_ct[:3, 3]
        for k in FEATURE_CLASSES:
            pts = np.asarray(model.points[k])
            if len(pts) == 0:
                continue
            if len(pts) > max_points_per_class:
                pts = pts[rng.choice(len(pts), int(max_points_per_class), replace=False)]
            transducer_pts[k] = pts @ R.T + t

    def draw(plotter, legend: bool) -> None:
        label = (lambda text: text) if legend else (lambda text: None)
        for i, view in enumerate(seq):
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
        if frames is not None:
            joints = frames[:, :3, 3]
            plotter.add_mesh(pv.lines_from_points(joints).tube(radius=32.0, n_sides=20), color=(0.55, 0.58, 0.62),
                             label=label("UR5e (DH link chain)"))
            for p in joints[1:]:
                plotter.add_mesh(pv.Sphere(radius=42.0, center=p), color=(0.3, 0.45, 0.65))
            z_base = frames[0, :3, 2]
            plotter.add_mesh(pv.Cylinder(center=joints[0] + 10.0 * z_base, direction=z_base, radius=90.0,
                                         height=20.0), color=(0.25, 0.25, 0.3))
        if T_ct is not None:
            R, t = T_ct[:3, :3], T_ct[:3, 3]
            for k, pts in transducer_pts.items():
                plotter.add_points(pts, color=np.array(FEATURE_COLOURS[k]) / 255, point_size=point_size,
                                   render_points_as_spheres=False,
                                   label=label("transducer") if k == Feature.TRANSDUCER else None)
            focal = R @ np.asarray(getattr(model, "focal_point_mm", np.zeros(3)), float) + t
            plotter.add_mesh(pv.Sphere(radius=3.0, center=focal), color="red", label=label("focal point"))
            apex = R @ np.array([0.0, 0.0, model.spec.radius_mm]) + t
            plotter.add_mesh(pv.Line(focal, apex), color="red", line_width=2)
            if frames is not None:
                plotter.add_mesh(pv.Tube(pointa=frames[-1, :3, 3], pointb=apex, radius=12.0), color=(0.4, 0.4, 0.4))
        if T_cp is not None:
            h = half_phantom
            box = pv.Box(bounds=(-h, h, -h, h, -h, h)).transform(T_cp, inplace=False)
            plotter.add_mesh(box, color=(0.85, 0.7, 0.45), opacity=0.35, label=label("phantom"))
            plotter.add_mesh(box.extract_feature_edges(), color=(0.55, 0.4, 0.2), line_width=2)
        if zone_centre is not None:
            plotter.add_mesh(pv.Sphere(radius=float(zone_radius_mm), center=zone_centre), color=(0.0, 0.75, 0.8),
                             opacity=0.5, label=label("treated zone"))
        if target is not None:
            plotter.add_mesh(pv.Sphere(radius=2.0, center=target), color=(0.1, 0.8, 0.1), label=label("target"))

    def aim(plotter, bounds=None) -> None:
        plotter.reset_camera(bounds=bounds)
        focus = np.asarray(plotter.camera.focal_point)
        distance = plotter.camera.distance
        plotter.camera.position = tuple(focus + distance * direction / np.linalg.norm(direction))
        plotter.camera.focal_point = tuple(focus)
        plotter.camera.up = (0.0, -1.0, 0.0)
        plotter.reset_camera(bounds=bounds)

    # The close-up: the transducer, the phantom and the target (what lies near the focal point).
    near = [np.atleast_2d(v) for v in (target, zone_centre) if v is not None]
    if T_cp is not None:
        near.append(T_cp[:3, 3][None] + np.array([[-1.0], [1.0]]) * half_phantom)
    if T_ct is not None:
        near.append(np.vstack(list(transducer_pts.values()) or [T_ct[:3, 3][None]]))
    panels = 2 if close_up and near else 1
    plotter = pv.Plotter(off_screen=True, window_size=[width, height], shape=(1, panels), border=False)
    plotter.set_background("white")
    plotter.subplot(0, 0)
    draw(plotter, legend=True)
    plotter.add_legend(bcolor="white", face="circle", size=(0.3 if panels == 2 else 0.24, 0.26), loc="lower right")
    plotter.add_axes(xlabel="x (L)", ylabel="y (P)", zlabel="z (S)")
    aim(plotter)
    if zoom != 1.0:
        plotter.camera.zoom(float(zoom))
    if panels == 2:
        plotter.subplot(0, 1)
        draw(plotter, legend=False)
        pts = np.vstack(near)
        lo, hi = pts.min(axis=0) - 10.0, pts.max(axis=0) + 10.0
        aim(plotter, bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        plotter.camera.zoom(1.2)
        plotter.add_text("close-up: transducer, phantom, target", position="upper_left", font_size=10, color="black")
    image = plotter.screenshot(return_img=True)
    plotter.close()
    return np.asarray(image, dtype=np.uint8)
