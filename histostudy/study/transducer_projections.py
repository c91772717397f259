"""Notebook 01: the digital transducer model (§II-B.1) and synthetic biplane projections (§II-A
eq. 1-2, §II-B.2).

Builds the digital model at the pose-estimation and the rendering grid spacing and the physical
transducer that makes the images, measures the built points (point counts per class, the cap's
sphere fit, aperture and cutout sizes, in mm, transducer frame) so that the report sets measured
geometry beside the paper's numbers, renders one biplane pair (plane A at -45°, plane B at +45°,
§II-D) of the transducer in a known C-arm pose, tabulates the label content of the frames and the
projection geometry (pixels), and times the renderer (seconds).

The ``record_*`` functions write a section through ``writer``, a
:class:`histostudy.reporting.SectionWriter` (any object with its ``value``, ``compare``,
``table``, ``text`` and ``stand_in`` methods: this layer sits below ``reporting`` and does not
import it), and return what the notebook shows. Frames, units and seeding:
``docs/architecture.md``.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Callable, ContextManager, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from histostudy.core import as_generator
from histostudy.geometry import fit_sphere
from histostudy.imaging import default_biplane, random_background, render_frame, render_line_integrals
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, TransducerSpec, pose_facing

__all__ = [
    "SECTION",
    "TITLE",
    "BiplanePair",
    "StageGenerators",
    "TransducerModels",
    "build_models",
    "example_pose",
    "label_fraction_table",
    "model_geometry",
    "point_count_table",
    "record_label_content",
    "record_model_geometry",
    "record_point_counts",
    "record_render_timing",
    "record_stand_ins",
    "render_biplane_pair",
    "render_timing",
    "stage_generators",
    "view_geometry_table",
]

SECTION = "01_transducer_and_projections"
TITLE = "01 · Digital transducer model and synthetic biplane fluoroscopy (§II-A, §II-B.1, §II-B.2)"

#: ``timer(name)`` -> context manager that records the block's wall time (``SectionWriter.timer``).
Timer = Callable[[str], ContextManager]


def _untimed(name: str) -> ContextManager:
    return contextlib.nullcontext()


class StageGenerators(NamedTuple):
    """One independent Generator per stage of the notebook, so that drawing more in one stage
    (a finer 3-D scene, say) shifts no other stage's numbers."""

    physical: np.random.Generator
    background: np.random.Generator
    render: np.random.Generator
    scene: np.random.Generator


def stage_generators(seed: int) -> StageGenerators:
    """The four stage Generators spawned from the study ``seed`` (``SeedSequence(seed).spawn(4)``)."""
    return StageGenerators(*(np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)))


@dataclass(frozen=True)
class TransducerModels:
    """The models of the study: the digital model at the pose-estimation spacing (``pose``) and at
    the rendering spacing (``render``, also the reference labels), and the physical transducer
    (``physical``, rendering spacing) that makes the images."""

    spec: TransducerSpec
    pose: TransducerModel
    render: TransducerModel
    physical: TransducerModel


def build_models(pose_spacing_mm: float, render_spacing_mm: float, *, rng: np.random.Generator,
                 spec: TransducerSpec | None = None, timer: Timer | None = None) -> TransducerModels:
    """Build the three models of :class:`TransducerModels`; ``rng`` draws the physical
    transducer's manufacturing deviation, ``timer`` (optional) times each build."""
    spec = TransducerSpec() if spec is None else spec
    timer = _untimed if timer is None else timer
    with timer(f"build digital model {pose_spacing_mm} mm"):
        pose_model = TransducerModel.build(spec, spacing_mm=pose_spacing_mm)
    with timer(f"build digital model {render_spacing_mm} mm"):
        render_model = TransducerModel.build(spec, spacing_mm=render_spacing_mm)
    with timer(f"build physical model {render_spacing_mm} mm"):
        physical = TransducerModel.build_physical(spec, spacing_mm=render_spacing_mm, rng=rng)
    return TransducerModels(spec, pose_model, render_model, physical)


def point_count_table(models: Mapping[str, TransducerModel]) -> pd.DataFrame:
    """Points per feature class (rows) for each model (columns, e.g. ``"0.47 mm"``), with a total."""
    data = {name: [len(m.points[k]) for k in FEATURE_CLASSES] for name, m in models.items()}
    table = pd.DataFrame(data, index=[k.name.lower() for k in FEATURE_CLASSES])
    table.loc["total"] = table.sum()
    table.index.name = "feature class"
    return table.reset_index()


def model_geometry(model: TransducerModel) -> dict:
    """Geometry measured on the built points (mm): cap sphere fit, aperture widths, cutout diameter.

    The cap is every point on the spherical surface (elements and the boundary bands): points
    whose distance from the focal point is the cap radius to within half a grid step.
    """
    spec = model.spec
    surface = []
    for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS):
        pts = model.points[k]
        r = np.linalg.norm(pts, axis=1)
        surface.append(pts[np.abs(r - spec.radius_mm) <= 0.5 * model.spacing_mm + 1e-9])
    surface = np.vstack(surface)
    centre, radius = fit_sphere(model.points[Feature.TRANSDUCER])
    radial_xy = np.hypot(surface[:, 0], surface[:, 1])
    return {
        "sphere_radius_mm": radius,
        "sphere_centre_mm": centre,
        "aperture_x_mm": float(np.ptp(surface[:, 0])),
        "aperture_y_mm": float(np.ptp(surface[:, 1])),
        "cutout_diameter_mm": float(2.0 * radial_xy.min()),
        "cap_depth_mm": float(np.ptp(surface[:, 2])),
    }


def record_point_counts(writer, models: TransducerModels) -> pd.DataFrame:
    """Record and return the points per class of the three models (table ``point_counts``)."""
    counts = point_count_table({f"{models.pose.spacing_mm} mm (pose)": models.pose,
                                f"{models.render.spacing_mm} mm (render)": models.render,
                                f"{models.physical.spacing_mm} mm physical": models.physical})
    writer.table("point_counts", counts, "Model points per feature class")
    return counts


def record_model_geometry(writer, models: TransducerModels) -> dict:
    """Record the rendering model's measured geometry beside the paper's (§II-B.1), the grid
    spacings, and the physical transducer's focal-point shift from the digital one (mm); returns
    :func:`model_geometry` of the rendering model."""
    geometry = model_geometry(models.render)
    writer.value("model_geometry", geometry)
    writer.value("spec", models.spec.to_dict())
    writer.compare("model.radius_mm", "Cap sphere radius (least-squares fit of element points)",
                   geometry["sphere_radius_mm"], unit="mm", digits=3)
    writer.compare("model.cutout_diameter_mm", "Central cutout diameter (measured)",
                   geometry["cutout_diameter_mm"], unit="mm", digits=1)
    writer.compare("model.aperture_mm", "Aperture, LR x TB (measured)",
                   f"{geometry['aperture_x_mm']:.1f} x {geometry['aperture_y_mm']:.1f} mm")
    writer.compare("model.spacing_pose_mm", "Grid spacing, pose-estimation model", models.pose.spacing_mm, unit="mm")
    writer.compare("model.spacing_render_mm", "Grid spacing, rendering model", models.render.spacing_mm,
                   unit="mm", digits=3)
    writer.compare("model.n_feature_classes", "Feature classes with points",
                   int(sum(len(v) > 0 for v in models.render.points.values())))
    focal_shift_mm = float(np.linalg.norm(models.physical.focal_point_mm))
    writer.value("physical_focal_point_shift_mm", focal_shift_mm)
    writer.compare("physical.focal_shift_mm", "Physical vs digital focal point (manufacturing deviation)",
                   focal_shift_mm, unit="mm", paper_key="",
                   note="stands in for the bias the paper attributes to model mismatch (§IV)")
    return geometry


def example_pose() -> np.ndarray:
    """``T_carm_transducer`` of the example pair: the transducer above the supine patient, its
    axis tilted off the anteroposterior line, turned 0.35 rad about it, and its focal point a few
    mm from the isocentre (C-arm frame, mm)."""
    return pose_facing((0.15, 1.0, 0.25), focal_point_mm=(4.0, -6.0, 8.0), axial_rotation_rad=0.35)


@dataclass(frozen=True)
class BiplanePair:
    """One rendered biplane pair: the views, the true ``T_carm_transducer``, the background
    scene (an ``Anatomy``) and the two frames (plane A, plane B)."""

    views: tuple
    T_carm_transducer: np.ndarray
    anatomy: object
    frames: list


def render_biplane_pair(models: TransducerModels, background: str, *, rng_background: np.random.Generator,
                        rng_render: np.random.Generator, T_carm_transducer=None, timer: Timer | None = None,
                        **render_kwargs) -> BiplanePair:
    """Render the physical transducer in ``T_carm_transducer`` (default :func:`example_pose`) on
    a random ``background`` scene (``"abdomen"``, ``"phantom"``, ``"mixed"``) in both planes of
    :func:`~histostudy.imaging.default_biplane`, labelled by the rendering model (Fig. 5 A-C).

    ``render_kwargs`` go to :func:`~histostudy.imaging.render_frame` (photons_per_pixel,
    n_splats, splat_sigma_mm); ``timer`` (optional) times the rendering of the pair.
    """
    timer = _untimed if timer is None else timer
    views = default_biplane()
    T_carm_transducer = example_pose() if T_carm_transducer is None else T_carm_transducer
    anatomy = random_background(rng_background, background)
    with timer("render biplane pair"):
        frames = [render_frame(models.render, T_carm_transducer, view, rng=rng_render, physical=models.physical,
                               background=anatomy, **render_kwargs) for view in views]
    return BiplanePair(views, T_carm_transducer, anatomy, frames)


def label_fraction_table(frames: Sequence) -> pd.DataFrame:
    """Pixels per label class in each frame's reference labels (count and percent of the image)."""
    rows = []
    for frame in frames:
        counts = np.bincount(frame.labels.ravel(), minlength=len(Feature))
        for k in Feature:
            rows.append({"view": frame.view.name, "class": k.name.lower(), "pixels": int(counts[k]),
                         "percent": 100.0 * counts[k] / frame.labels.size})
    return pd.DataFrame(rows)


def view_geometry_table(frames: Sequence, T_carm_transducer) -> pd.DataFrame:
    """Per frame: the view's gantry parameters, the pixel ``(u, v)`` of the focal point (eq. 1-2)
    and the network input size (the detector scaled by 0.25, ``cols x rows``)."""
    rows = []
    for frame in frames:
        focal_px = frame.view.project(np.asarray(T_carm_transducer)[:3, 3])[0]
        rows.append({"view": frame.view.name, **frame.view.gantry,
                     "focal point u (px)": focal_px[0], "focal point v (px)": focal_px[1],
                     "network input (0.25x)": "x".join(map(str, frame.view.scaled(0.25).shape[::-1]))})
    return pd.DataFrame(rows)


def record_label_content(writer, pair: BiplanePair) -> pd.DataFrame:
    """Record the label pixels per class and view, the feature classes visible in both views,
    and the projection geometry of the two planes; returns the label percentages as a
    class x view table."""
    labels = label_fraction_table(pair.frames)
    writer.table("label_pixels", labels, "Reference label pixels per class and view", digits=2)
    n_foreground_classes = labels[labels["pixels"] > 0].groupby("view")["class"].nunique() - 1
    writer.compare("model.n_feature_classes", "Feature classes visible in each view", int(n_foreground_classes.min()),
                   note="min over both planes")
    geometry = view_geometry_table(pair.frames, pair.T_carm_transducer)
    writer.table("views", geometry, "Projection geometry of the two planes")
    writer.compare("carm.gantry_angles_deg", "Gantry angles (plane A, plane B)",
                   f"{pair.views[0].gantry['primary_deg']:+.0f}°, {pair.views[1].gantry['primary_deg']:+.0f}° around PA")
    writer.compare("carm.network_input_px", "Network input size (detector x 0.25)", geometry["network input (0.25x)"][0])
    return labels.pivot(index="class", columns="view", values="percent")


def render_timing(model: TransducerModel, T_carm_transducer, view, *, background, rng, physical=None,
                  repeats: int = 1, **render_kwargs) -> pd.DataFrame:
    """Wall time (s) of the stages of one synthetic frame, the median over ``repeats``.

    Stages: the background's projection, the transducer's splatting (:func:`render_line_integrals`)
    and the whole :func:`render_frame` (splatting, labels, background, noise). ``rng`` (a seed or
    a Generator) draws the splats and the noise of every repeat.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    rng = as_generator(rng)
    stages = {"background projection": [], "transducer splatting": [], "frame, background precomputed": []}
    image_model = physical if physical is not None else model
    splat_kwargs = {k: v for k, v in render_kwargs.items() if k in ("n_splats", "splat_sigma_mm")}
    for _ in range(repeats):
        t0 = time.perf_counter()
        bg = background.line_integrals(view) if hasattr(background, "line_integrals") else background
        stages["background projection"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        render_line_integrals(image_model, T_carm_transducer, view, rng=rng, **splat_kwargs)
        stages["transducer splatting"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        render_frame(model, T_carm_transducer, view, rng=rng, physical=physical, background=bg, **render_kwargs)
        stages["frame, background precomputed"].append(time.perf_counter() - t0)
    n_points = sum(len(p) for p in image_model.points.values())
    table = pd.DataFrame([{"stage": name, "median_s": float(np.median(t)), "repeats": len(t),
                           "points": n_points if name != "background projection" else pd.NA,
                           "detector": f"{view.shape[1]}x{view.shape[0]}"} for name, t in stages.items()])
    return table.astype({"points": "Int64"})


def record_render_timing(writer, models: TransducerModels, pair: BiplanePair, *, repeats: int, rng,
                         **render_kwargs) -> pd.DataFrame:
    """Record and return :func:`render_timing` of plane A's frame of ``pair``, with the splatting
    parameters (``n_splats``, ``splat_sigma_mm`` in ``render_kwargs``) beside the paper's."""
    view = pair.views[0]
    timing = render_timing(models.render, pair.T_carm_transducer, view, background=pair.anatomy,
                           physical=models.physical, repeats=repeats, rng=rng, **render_kwargs)
    writer.table("render_timing", timing, f"Render time of one {view.shape[1]}x{view.shape[0]} frame "
                 f"(median of {repeats})")
    writer.compare("render.n_splats", "Splats per point", render_kwargs["n_splats"])
    writer.compare("render.splat_sigma_mm", "Splat offset SD", render_kwargs["splat_sigma_mm"], unit="mm")
    return timing


def record_stand_ins(writer, models: TransducerModels, *, background: str, photons_per_pixel: float,
                     n_splats: int) -> None:
    """Record what stands in for the lab's transducer, projections and annotation, and how the
    frames were made."""
    writer.stand_in("the HistoSonics transducer", "a physical model: per-quadrant manufacturing offsets/tilts and "
                    "probe-mount screws that the digital model lacks")
    writer.stand_in("porcine and phantom projections (Artis zee, line integrals)",
                    "exact cone-beam projections of a procedural 3-D abdomen or phantom scene")
    writer.stand_in("manual annotation (digital model aligned by hand)", "the digital model in the known true pose")
    writer.text(f"The cap radius, cutout and aperture are measured on the built points, not copied from the spec. "
                f"Frames splat the {models.physical.spacing_mm} mm physical model "
                f"({sum(models.physical.n_points.values()):,} points x {n_splats} splats) onto a '{background}' "
                f"background at {photons_per_pixel:.0f} photons per pixel.")
