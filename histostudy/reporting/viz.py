"""Figures the notebooks share: colour-coded label maps (Fig. 5), the pose overlay (Fig. 6) and
off-screen 3-D scenes (pyvista; EGL where there is no display). Figures are returned, never shown or
saved here: a notebook records them through a :class:`~histostudy.reporting.report.SectionWriter`."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from histostudy.transducer import FEATURE_CLASSES, Feature

from ._targeting_parts import (
    _check_pairs,
    _checked_points,
    _checked_render_options,
    _checked_transforms,
    _half_phantom,
    _render,
    _TargetingScene,
    _transducer_points,
)

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



def _rgb(colour) -> tuple[float, float, float]:
    """An 8-bit ``(r, g, b)`` as matplotlib's 0-1 floats."""
    r, g, b = (float(c) / 255.0 for c in colour)
    return r, g, b

def label_rgb(labels: np.ndarray) -> np.ndarray:
    """Colour a label map with the paper's Fig. 5 colours (:data:`FEATURE_COLOURS`).

    Args:
        labels: ``(rows, cols)`` class indices (:class:`~histostudy.transducer.Feature`, 0-255).

    Returns:
        ``(rows, cols, 3)`` uint8 RGB image; classes without a colour are black.
    """
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
    reference labels blended over the image).

    Args:
        frames: :class:`~histostudy.imaging.Frame` objects (``image``, ``labels`` or None, ``view``).
        predictions: one ``(rows, cols)`` label map per frame, or None.
        titles: one title per frame (default ``"plane <view name>"``).
        panel_inches: the height of one panel (inches).

    Returns:
        The matplotlib figure (not shown).
    """
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
    handles = [Patch(color=_rgb(FEATURE_COLOURS[k]), label=FEATURE_NAMES[k]) for k in FEATURE_CLASSES]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def plot_pose_overlay(frames: Sequence, model, T_carm_transducer, *, rng: np.random.Generator,
                      max_points_per_class: int = 4000, titles: Sequence[str] | None = None,
                      panel_inches: float = 3.6):
    """Fig. 6, columns 1-2, for each frame (one row per view): the X-ray image, and the image with
    the digital model's points projected in the estimated pose (coloured by class) and the
    projected focal point (red cross).

    Args:
        frames: :class:`~histostudy.imaging.Frame` objects (``image``, ``view``).
        model: the :class:`~histostudy.transducer.TransducerModel` (points in transducer mm).
        T_carm_transducer: 4x4 estimated pose, mapping transducer -> C-arm (mm).
        rng: draws the subset of each class's points.
        max_points_per_class: at most this many points drawn per class.
        titles: one title per frame (default ``"plane <view name>"``).
        panel_inches: the height of one panel (inches).

    Returns:
        The matplotlib figure (not shown).
    """
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
            axes[i, 1].scatter(px[:, 0], px[:, 1], s=0.3, color=_rgb(FEATURE_COLOURS[k]), alpha=0.6,
                               linewidths=0)
        focal = frame.view.project(T[:3, :3] @ np.asarray(model.focal_point_mm, float) + T[:3, 3])[0]
        axes[i, 1].plot(*focal, "r+", markersize=12, markeredgewidth=2)
        rows, cols = frame.shape
        axes[i, 1].set_xlim(-0.5, cols - 0.5)
        axes[i, 1].set_ylim(rows - 0.5, -0.5)
    handles = [Line2D([], [], marker="o", linestyle="", color=_rgb(FEATURE_COLOURS[k]),
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
    """Off-screen pyvista render of a transducer model's points coloured by class, its focal point
    as a red sphere and its axis as a line.

    Args:
        model: the :class:`~histostudy.transducer.TransducerModel` (transducer frame, mm).
        rng: draws the subset of each class's points.
        max_points_per_class: at most this many points drawn per class.
        window_size: ``(width, height)`` of the image (pixels).
        point_size: the points' size on screen (pixels).
        camera_elevation_deg: the camera's elevation from the x-z view (deg).
        camera_azimuth_deg: the camera's azimuth from the x-z view (deg).

    Returns:
        ``(height, width, 3)`` uint8 RGB image.
    """
    _prepare_offscreen()
    import pyvista as pv

    plotter = pv.Plotter(off_screen=True, window_size=list(window_size))
    plotter.set_background("white")  # type: ignore[arg-type]  # pyvista's decorated method types
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
    plotter.add_legend(bcolor="white", face="circle", size=(0.22, 0.22))  # type: ignore[call-arg]  # pyvista's types
    plotter.camera_position = "xz"
    plotter.camera.elevation = camera_elevation_deg
    plotter.camera.azimuth = camera_azimuth_deg
    plotter.reset_camera()  # type: ignore[call-arg]  # pyvista's decorated method types
    plotter.camera.zoom(1.3)
    image = plotter.screenshot(return_img=True)
    plotter.close()
    return np.asarray(image, dtype=np.uint8)


def targeting_scene(views, *, T_carm_base=None, joints_rad=None, model=None, T_carm_transducer=None,
                    rng: np.random.Generator | None = None, phantom_spec=None, T_carm_phantom=None,
                    target_mm=None, zone_centre_mm=None, zone_radius_mm=None,
                    window_size: tuple[int, int] = (1600, 800), max_points_per_class: int = 20000,
                    point_size: float = 2.0, camera_direction=(-0.55, -0.5, -1.0), zoom: float = 1.0,
                    close_up: bool = True) -> np.ndarray:
    """Off-screen pyvista render of the targeting set-up (§II-C, §II-D, Fig. 2), drawn in the C-arm
    (CBCT, world) frame, LPS, mm, anterior (world -y) up. With ``close_up`` (and a transducer,
    phantom, target or zone to show) the window is split: the whole scene on the left, on the right
    the same scene from the same direction framed on the transducer, phantom, target and zone.

    Args:
        views: the C-arm views (:class:`~histostudy.imaging.carm.View`, e.g.
            :func:`~histostudy.imaging.carm.default_biplane`): each drawn as its X-ray source (a
            sphere), its detector (a thin rectangle) and the beam's frustum, one colour per plane.
        T_carm_base: 4x4 pose of the robot base, mapping base -> C-arm (mm); with ``joints_rad`` the
            arm is drawn as tubes between its DH frames' origins
            (:func:`histostudy.robot.kinematics.joint_frames`).
        joints_rad: the 6 UR5e joint angles (rad); given with ``T_carm_base`` or not at all.
        model: the :class:`~histostudy.transducer.TransducerModel`, drawn with ``T_carm_transducer``
            as its points coloured by class (:data:`FEATURE_COLOURS`), its focal point as a red
            sphere and, with the robot, the mount from the flange to the cap's apex.
        T_carm_transducer: 4x4 pose, mapping transducer -> C-arm (mm); given with ``model``.
        rng: draws the subset of each class's points; required with ``model``.
        phantom_spec: the phantom cube (default :class:`~histostudy.imaging.cbct.PhantomSpec`);
            needs ``T_carm_phantom``.
        T_carm_phantom: 4x4 pose, mapping phantom -> C-arm (mm); the phantom drawn as a
            semi-transparent box.
        target_mm: the target, 3 C-arm coordinates (mm), drawn as a green sphere.
        zone_centre_mm: the treated zone's centre, 3 C-arm coordinates (mm); given with
            ``zone_radius_mm``, drawn as a semi-transparent cyan sphere.
        zone_radius_mm: the zone's radius (mm, finite, > 0).
        window_size: ``(width, height)`` of the image (pixels, each at least 16).
        max_points_per_class: at most this many model points drawn per class (>= 1).
        point_size: the points' size on screen (pixels).
        camera_direction: world vector from the scene's centre towards the camera (non-zero; default:
            from the patient's right, anterior and feet).
        zoom: the camera's zoom after framing the whole scene.
        close_up: split the window into the whole scene and a close-up.

    Returns:
        ``(height, width, 3)`` uint8 RGB image.

    Raises:
        ValueError: naming the argument: half of a pair given (``T_carm_base``/``joints_rad``,
            ``model``/``T_carm_transducer``, ``zone_centre_mm``/``zone_radius_mm``, ``phantom_spec``
            without ``T_carm_phantom``), ``model`` without ``rng``, a transform that is not 4x4 rigid,
            not 6 joint angles, a point that is not 3 finite numbers, a radius that is not > 0, a
            window under 16 x 16 pixels, a zero ``camera_direction`` or ``max_points_per_class`` < 1.
    """
    from histostudy.imaging.carm import views_from_sequence

    seq = views_from_sequence(views)
    _check_pairs(T_carm_base=T_carm_base, joints_rad=joints_rad, model=model, T_carm_transducer=T_carm_transducer,
                 rng=rng, zone_centre_mm=zone_centre_mm, zone_radius_mm=zone_radius_mm, phantom_spec=phantom_spec,
                 T_carm_phantom=T_carm_phantom)
    frames, T_ct, T_cp = _checked_transforms(T_carm_base, joints_rad, T_carm_transducer, T_carm_phantom)
    target, zone_centre = _checked_points(target_mm, zone_centre_mm, zone_radius_mm)
    width, height, direction = _checked_render_options(window_size, camera_direction, max_points_per_class)

    _prepare_offscreen()
    transducer_pts = _transducer_points(model, T_ct, rng, max_points_per_class)
    scene = _TargetingScene(views=seq, frames=frames, T_ct=T_ct, model=model, transducer_pts=transducer_pts,
                            colours={k: np.array(FEATURE_COLOURS[k]) / 255 for k in transducer_pts}, T_cp=T_cp,
                            half_phantom=_half_phantom(T_cp, phantom_spec), target=target, zone_centre=zone_centre,
                            zone_radius_mm=zone_radius_mm)
    return _render(scene, width=width, height=height, direction=direction, zoom=zoom, close_up=close_up,
                   point_size=point_size)
