"""Notebook 01: the digital transducer model (§II-B.1) and synthetic biplane projections (§II-A
eq. 1-2, §II-B.2).

Builds the digital model at the pose-estimation and the rendering grid spacing and the physical
transducer that makes the images, measures the built points (point counts per class, the cap's
sphere fit, aperture and cutout sizes, in mm, transducer frame) so that the report sets measured
geometry beside the paper's numbers, renders one biplane pair (plane A at -45°, plane B at +45°,
§II-D) of the transducer in a known C-arm pose, tabulates the label content of the frames and the
projection geometry (pixels), and times the renderer (seconds).

The section's interface (:mod:`.section`): :class:`TransducerProjectionsConfig` (the notebook's
parameters, checked), :func:`prepare` (the stage generators and the models, in a
:class:`TransducerProjectionsSetup`), then the ``*_part`` functions returning each heading's
tables, values and comparisons as a :class:`~.section.SectionPart` that :func:`~.section.record`
writes through a :class:`histostudy.reporting.SectionWriter` (this layer sits below ``reporting``
and does not import it). Frames, units and seeding:
``docs/architecture.md``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from histostudy.core import as_generator, check_count, check_positive
from histostudy.geometry import fit_sphere
from histostudy.imaging import BACKGROUNDS, default_biplane, random_background, render_frame, render_line_integrals
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, TransducerSpec, pose_facing

from .section import RenderedSectionConfig, SectionPart, Timer, check_bool, check_choice, record, timer_or_untimed

__all__ = [
    "RECORDED_PARAMETERS",
    "SECTION",
    "TITLE",
    "BiplanePair",
    "StageGenerators",
    "TransducerModels",
    "TransducerProjectionsConfig",
    "TransducerProjectionsSetup",
    "build_models",
    "example_pose",
    "label_content_part",
    "label_fraction_table",
    "label_percentages",
    "model_geometry",
    "model_geometry_part",
    "point_count_table",
    "point_counts_part",
    "prepare",
    "record",
    "render_biplane_pair",
    "render_timing",
    "render_timing_part",
    "stage_generators",
    "stand_ins_part",
    "view_geometry_table",
]

SECTION = "01_transducer_and_projections"
TITLE = "01 · Digital transducer model and synthetic biplane fluoroscopy (§II-A, §II-B.1, §II-B.2)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "pose_spacing_mm", "render_spacing_mm",
                       "background", "timing_repeats")


@dataclass(frozen=True)
class TransducerProjectionsConfig(RenderedSectionConfig):
    """Notebook 01's parameters, checked: the frames' dose and splatting (``photons_per_pixel``,
    ``n_splats``, ``splat_sigma_mm`` in mm), the model grids (``pose_spacing_mm``,
    ``render_spacing_mm``), the scene ``background`` (one of :data:`~histostudy.imaging.BACKGROUNDS`),
    the render timing's ``timing_repeats`` and whether to draw the 3-D model (``render_3d``).

    A bad value raises ValueError naming the parameter, its value and what it must be.
    """

    NOTEBOOK = "01"
    RECORDED = RECORDED_PARAMETERS

    timing_repeats: int
    render_3d: bool

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        for name, unit in (("photons_per_pixel", "photons per pixel"), ("splat_sigma_mm", "mm"),
                           ("pose_spacing_mm", "mm"), ("render_spacing_mm", "mm")):
            put(name, check_positive(getattr(self, name), name, unit=unit))
        for name in ("n_splats", "timing_repeats"):
            put(name, check_count(getattr(self, name), name))
        check_choice(self.background, "background", BACKGROUNDS)
        put("render_3d", check_bool(self.render_3d, "render_3d"))



    def render(self) -> dict:
        """The frames' dose and splatting (:func:`~histostudy.imaging.render_frame` keywords)."""
        return {"photons_per_pixel": self.photons_per_pixel, "n_splats": self.n_splats,
                "splat_sigma_mm": self.splat_sigma_mm}


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
    timer = timer_or_untimed(timer)
    with timer(f"build digital model {pose_spacing_mm} mm"):
        pose_model = TransducerModel.build(spec, spacing_mm=pose_spacing_mm)
    with timer(f"build digital model {render_spacing_mm} mm"):
        render_model = TransducerModel.build(spec, spacing_mm=render_spacing_mm)
    with timer(f"build physical model {render_spacing_mm} mm"):
        physical = TransducerModel.build_physical(spec, spacing_mm=render_spacing_mm, rng=rng)
    return TransducerModels(spec, pose_model, render_model, physical)


@dataclass(frozen=True)
class TransducerProjectionsSetup:
    """What notebook 01 runs on: its ``params``, the ``seed``, the stage generators ``rngs``
    (:func:`stage_generators`) and the ``models`` (:func:`build_models`)."""

    params: TransducerProjectionsConfig
    seed: int
    rngs: StageGenerators
    models: TransducerModels


def prepare(params: TransducerProjectionsConfig | Mapping, seed: int, *,
            timer: Timer | None = None) -> TransducerProjectionsSetup:
    """The section's set-up: the stage generators of ``seed`` and the models on the parameters'
    grids (the physical transducer drawn from ``rngs.physical``; ``timer`` times each build)."""
    if not isinstance(params, TransducerProjectionsConfig):
        params = TransducerProjectionsConfig.from_parameters(params)
    rngs = stage_generators(seed)
    models = build_models(params.pose_spacing_mm, params.render_spacing_mm, rng=rngs.physical, timer=timer)
    return TransducerProjectionsSetup(params, seed, rngs, models)


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


def point_counts_part(models: TransducerModels) -> SectionPart:
    """The points per class of the three models (table ``point_counts``)."""
    counts = point_count_table({f"{models.pose.spacing_mm} mm (pose)": models.pose,
                                f"{models.render.spacing_mm} mm (render)": models.render,
                                f"{models.physical.spacing_mm} mm physical": models.physical})
    return SectionPart(tables={"point_counts": (counts, "Model points per feature class")})




def model_geometry_part(models: TransducerModels) -> SectionPart:
    """The rendering model's measured geometry (:func:`model_geometry`, value ``model_geometry``)
    beside the paper's (§II-B.1), the grid spacings, and the physical transducer's focal-point shift
    from the digital one (mm)."""
    geometry = model_geometry(models.render)
    focal_shift_mm = float(np.linalg.norm(models.physical.focal_point_mm))
    comparisons = (
        dict(key="model.radius_mm", label="Cap sphere radius (least-squares fit of element points)",
             ours=geometry["sphere_radius_mm"], unit="mm", digits=3),
        dict(key="model.cutout_diameter_mm", label="Central cutout diameter (measured)",
             ours=geometry["cutout_diameter_mm"], unit="mm", digits=1),
        dict(key="model.aperture_mm", label="Aperture, LR x TB (measured)",
             ours=f"{geometry['aperture_x_mm']:.1f} x {geometry['aperture_y_mm']:.1f} mm"),
        dict(key="model.spacing_pose_mm", label="Grid spacing, pose-estimation model", ours=models.pose.spacing_mm,
             unit="mm"),
        dict(key="model.spacing_render_mm", label="Grid spacing, rendering model", ours=models.render.spacing_mm,
             unit="mm", digits=3),
        dict(key="model.n_feature_classes", label="Feature classes with points",
             ours=int(sum(len(v) > 0 for v in models.render.points.values()))),
        dict(key="physical.focal_shift_mm", label="Physical vs digital focal point (manufacturing deviation)",
             ours=focal_shift_mm, unit="mm", paper_key="",
             note="stands in for the bias the paper attributes to model mismatch (§IV)"))
    return SectionPart(values={"model_geometry": geometry, "spec": models.spec.to_dict(),
                               "physical_focal_point_shift_mm": focal_shift_mm}, comparisons=comparisons)




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
    timer = timer_or_untimed(timer)
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


def label_content_part(pair: BiplanePair) -> SectionPart:
    """The label pixels per class and view (table ``label_pixels``), the feature classes visible in
    both views, and the projection geometry of the two planes (table ``views``)."""
    labels = label_fraction_table(pair.frames)
    n_foreground_classes = labels[labels["pixels"] > 0].groupby("view")["class"].nunique() - 1
    geometry = view_geometry_table(pair.frames, pair.T_carm_transducer)
    gantry = f"{pair.views[0].gantry['primary_deg']:+.0f}°, {pair.views[1].gantry['primary_deg']:+.0f}° around PA"
    return SectionPart(
        tables={"label_pixels": (labels, "Reference label pixels per class and view", {"digits": 2}),
                "views": (geometry, "Projection geometry of the two planes")},
        comparisons=(dict(key="model.n_feature_classes", label="Feature classes visible in each view",
                          ours=int(n_foreground_classes.min()), note="min over both planes"),
                     dict(key="carm.gantry_angles_deg", label="Gantry angles (plane A, plane B)", ours=gantry),
                     dict(key="carm.network_input_px", label="Network input size (detector x 0.25)",
                          ours=geometry["network input (0.25x)"][0])))


def label_percentages(labels: pd.DataFrame) -> pd.DataFrame:
    """:func:`label_fraction_table`'s percentages as a class x view table."""
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


def render_timing_part(models: TransducerModels, pair: BiplanePair, *, repeats: int, rng,
                       **render_kwargs) -> SectionPart:
    """:func:`render_timing` of plane A's frame of ``pair`` (table ``render_timing``), with the
    splatting parameters (``n_splats``, ``splat_sigma_mm`` in ``render_kwargs``) beside the paper's."""
    view = pair.views[0]
    timing = render_timing(models.render, pair.T_carm_transducer, view, background=pair.anatomy,
                           physical=models.physical, repeats=repeats, rng=rng, **render_kwargs)
    return SectionPart(
        tables={"render_timing": (timing, f"Render time of one {view.shape[1]}x{view.shape[0]} frame "
                                          f"(median of {repeats})")},
        comparisons=(dict(key="render.n_splats", label="Splats per point", ours=render_kwargs["n_splats"]),
                     dict(key="render.splat_sigma_mm", label="Splat offset SD", ours=render_kwargs["splat_sigma_mm"],
                          unit="mm")))




def stand_ins_part(models: TransducerModels, *, background: str, photons_per_pixel: float,
                   n_splats: int) -> SectionPart:
    """What stands in for the lab's transducer, projections and annotation, and how the frames were
    made."""
    return SectionPart(stand_ins=(
        ("the HistoSonics transducer", "a physical model: per-quadrant manufacturing offsets/tilts and "
         "probe-mount screws that the digital model lacks"),
        ("porcine and phantom projections (Artis zee, line integrals)",
         "exact cone-beam projections of a procedural 3-D abdomen or phantom scene"),
        ("manual annotation (digital model aligned by hand)", "the digital model in the known true pose")),
        texts=(f"The cap radius, cutout and aperture are measured on the built points, not copied from the spec. "
               f"Frames splat the {models.physical.spacing_mm} mm physical model "
               f"({sum(models.physical.n_points.values()):,} points x {n_splats} splats) onto a '{background}' "
               f"background at {photons_per_pixel:.0f} photons per pixel.",))
