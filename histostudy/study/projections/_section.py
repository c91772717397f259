"""Notebook 01's section (§II-A eq. 1-2, §II-B.1, §II-B.2): its parameters, the digital and physical
transducer models, one synthetic biplane pair and its label content, and the render timing, each
heading's part a :class:`~histostudy.study.section.SectionPart` (docs/study-sections.md, "01").
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
from histostudy.imaging import (
    BACKGROUNDS,
    FrameRenderConfig,
    default_biplane,
    random_background,
    render_frame,
    render_line_integrals,
)
from histostudy.transducer import FEATURE_CLASSES, Feature, TransducerModel, TransducerSpec, pose_facing

from ..section import (
    RenderedSectionConfig,
    SectionPart,
    Timer,
    check_bool,
    check_choice,
    check_splat_device,
    timer_or_untimed,
)

SECTION = "01_transducer_and_projections"
TITLE = "01 · Digital transducer model and synthetic biplane fluoroscopy (§II-A, §II-B.1, §II-B.2)"

#: The notebook parameters the report records, in the order it records them.
RECORDED_PARAMETERS = ("photons_per_pixel", "n_splats", "splat_sigma_mm", "splat_device", "pose_spacing_mm",
                       "render_spacing_mm", "background", "timing_repeats")


@dataclass(frozen=True)
class TransducerProjectionsConfig(RenderedSectionConfig):
    """Notebook 01's parameters, checked; built from the parameters cell by
    ``TransducerProjectionsConfig.from_parameters(globals())``.

    Args:
        photons_per_pixel: unattenuated photons per detector pixel of the frames (dose, > 0).
        n_splats: splats per model point (>= 1).
        splat_sigma_mm: SD of each splat's jitter, mm (> 0).
        pose_spacing_mm: grid spacing of the pose-estimation model, mm (paper: 0.47).
        render_spacing_mm: grid spacing of the rendering (and reference-label) model, mm (paper: 0.125).
        background: the scene behind the transducer, one of :data:`histostudy.imaging.BACKGROUNDS`.
        splat_device: where the frames are splatted, one of :data:`~histostudy.study.section.STUDY_SPLAT_DEVICES`.
        timing_repeats: repeats of the render timing, whose median is reported (>= 1).
        render_3d: whether the notebook draws the 3-D model.

    Raises:
        ValueError: a bad value, naming the parameter, its value and what it must be (or, from
            ``from_parameters``, the parameters the mapping lacks).
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
        check_splat_device(self.splat_device)
        put("render_3d", check_bool(self.render_3d, "render_3d"))


    def render(self) -> dict:
        """The frames' dose, splatting and renderer (:func:`~histostudy.imaging.render_frame` keywords)."""
        return FrameRenderConfig(photons_per_pixel=self.photons_per_pixel, n_splats=self.n_splats,
                                 splat_sigma_mm=self.splat_sigma_mm, splat_device=self.splat_device).frame_kwargs()


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
    """The transducer models of notebook 01 (§II-B.1).

    Args:
        spec: the transducer's parametric specification.
        pose: the digital model at the pose-estimation spacing.
        render: the digital model at the rendering spacing (also the reference labels).
        physical: the physical transducer at the rendering spacing (manufacturing deviations
            drawn), which makes the images.
    """

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
    """What notebook 01 runs on (made by :func:`prepare`).

    Args:
        params: the checked parameters.
        seed: the study seed.
        rngs: one Generator per stage (``physical``, ``background``, ``render``, ``scene``),
            spawned from ``seed``.
        models: the digital and physical models.
    """

    params: TransducerProjectionsConfig
    seed: int
    rngs: StageGenerators
    models: TransducerModels


def prepare(params: TransducerProjectionsConfig | Mapping, seed: int, *,
            timer: Timer | None = None) -> TransducerProjectionsSetup:
    """The section's set-up: a Generator per stage spawned from ``seed`` and the models on the
    parameters' grids (the physical transducer drawn from ``rngs.physical``).

    Args:
        params: a :class:`TransducerProjectionsConfig`, or a mapping naming its fields (checked into one).
        seed: the study seed (``SeedSequence(seed).spawn(4)``).
        timer: ``timer(name)`` -> a context manager timing each model build (e.g.
            ``SectionWriter.timer``); None: untimed.

    Returns:
        The :class:`TransducerProjectionsSetup`.

    Raises:
        ValueError: a bad or missing parameter.
    """
    config = (params if isinstance(params, TransducerProjectionsConfig)
              else TransducerProjectionsConfig.from_parameters(params))
    rngs = stage_generators(seed)
    models = build_models(config.pose_spacing_mm, config.render_spacing_mm, rng=rngs.physical, timer=timer)
    return TransducerProjectionsSetup(config, seed, rngs, models)


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
    surface_parts: list[np.ndarray] = []
    for k in (Feature.TRANSDUCER, Feature.OUTER_BOUNDARY, Feature.INNER_BOUNDARY, Feature.GAPS):
        pts = model.points[k]
        r = np.linalg.norm(pts, axis=1)
        surface_parts.append(pts[np.abs(r - spec.radius_mm) <= 0.5 * model.spacing_mm + 1e-9])
    surface = np.vstack(surface_parts)
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
    """The points per feature class of the three models.

    Args:
        models: the set-up's models.

    Returns:
        A part with table ``point_counts`` (rows: feature classes and the total; columns: the models).
    """
    counts = point_count_table({f"{models.pose.spacing_mm} mm (pose)": models.pose,
                                f"{models.render.spacing_mm} mm (render)": models.render,
                                f"{models.physical.spacing_mm} mm physical": models.physical})
    return SectionPart(tables={"point_counts": (counts, "Model points per feature class")})


def model_geometry_part(models: TransducerModels) -> SectionPart:
    """The rendering model's geometry measured on its points beside the paper's (§II-B.1).

    Args:
        models: the set-up's models.

    Returns:
        A part with values ``model_geometry`` (cap sphere fit, aperture, cutout and cap depth, mm,
        transducer frame), ``spec`` and ``physical_focal_point_shift_mm`` (the physical focal point's
        distance from the digital one, mm), and the comparisons with the paper.
    """
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
    """One rendered biplane pair (:func:`render_biplane_pair`).

    Args:
        views: the two views (plane A, plane B).
        T_carm_transducer: the true pose, 4x4, maps transducer -> C-arm (mm).
        anatomy: the background scene.
        frames: the two frames (plane A, plane B), each with its reference labels.
    """

    views: tuple
    T_carm_transducer: np.ndarray
    anatomy: object
    frames: list


def render_biplane_pair(models: TransducerModels, background: str, *, rng_background: np.random.Generator,
                        rng_render: np.random.Generator, T_carm_transducer=None, timer: Timer | None = None,
                        **render_kwargs) -> BiplanePair:
    """Render the physical transducer on a random background in both planes of
    :func:`histostudy.imaging.default_biplane` (plane A at -45°, plane B at +45°), labelled by the
    rendering model (§II-B.2, Fig. 5 A-C).

    Args:
        models: the set-up's models (``physical`` makes the image, ``render`` the labels).
        background: the scene, ``"abdomen"``, ``"phantom"`` or ``"mixed"``.
        rng_background: draws the scene.
        rng_render: draws the splats and the photon noise, plane A then plane B.
        T_carm_transducer: the pose, 4x4, maps transducer -> C-arm (mm); None: :func:`example_pose`.
        timer: ``timer(name)`` -> a context manager timing the pair's rendering; None: untimed.
        **render_kwargs: :func:`histostudy.imaging.render_frame` keywords (``photons_per_pixel``,
            ``n_splats``, ``splat_sigma_mm``; :meth:`TransducerProjectionsConfig.render`).

    Returns:
        The :class:`BiplanePair`.

    Raises:
        ValueError: an unknown ``background`` or a bad render keyword (from the imaging layer).
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
    """The label content and projection geometry of a pair (eq. 1-2).

    Args:
        pair: the rendered pair.

    Returns:
        A part with table ``label_pixels`` (pixels and percent of each label class per view), table
        ``views`` (each view's gantry angles, the focal point's pixel ``(u, v)`` and the network
        input size) and the comparisons with the paper (feature classes visible in both views,
        gantry angles, network input size).
    """
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
    """The label percentages as a class x view table.

    Args:
        labels: the ``label_pixels`` table of :func:`label_content_part` (columns ``view``,
            ``class``, ``percent``).

    Returns:
        The percent of the image each class covers, one row per class, one column per view.
    """
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
    stages: dict[str, list[float]] = {"background projection": [], "transducer splatting": [],
                                      "frame, background precomputed": []}
    image_model = physical if physical is not None else model
    splat_kwargs = {k: v for k, v in render_kwargs.items() if k in ("n_splats", "splat_sigma_mm", "device")}
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
                           "detector": f"{view.shape[1]}x{view.shape[0]}",
                           "splat_device": render_kwargs.get("device") or "numpy"} for name, t in stages.items()])
    return table.astype({"points": "Int64"})


def render_timing_part(models: TransducerModels, pair: BiplanePair, *, repeats: int, rng,
                       **render_kwargs) -> SectionPart:
    """The wall time of the stages of plane A's frame of ``pair``, the median over ``repeats``
    (background projection, transducer splatting, the whole frame), with the splatting parameters
    beside the paper's (§II-B.2).

    Args:
        models: the set-up's models.
        pair: the rendered pair (its plane A view, pose and scene are timed).
        repeats: the timing repeats (>= 1).
        rng: a seed or a Generator drawing the splats and noise of every repeat.
        **render_kwargs: :func:`histostudy.imaging.render_frame` keywords; ``n_splats`` and
            ``splat_sigma_mm`` are required (compared with the paper).

    Returns:
        A part with table ``render_timing`` (seconds per stage) and the comparisons.

    Raises:
        ValueError: ``repeats`` < 1.
        KeyError: ``render_kwargs`` lacks ``n_splats`` or ``splat_sigma_mm``.
    """
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
    made.

    Args:
        models: the set-up's models (the physical model's spacing and points are named).
        background: the frames' scene.
        photons_per_pixel: the frames' dose, photons per pixel.
        n_splats: splats per model point.

    Returns:
        A part with the stand-ins and one paragraph.
    """
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
