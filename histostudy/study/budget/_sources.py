"""The lab's error sources (§IV), each a named, documented, switchable field of
:class:`LabErrorModel` (``None``: off), one lab's draws of them (:func:`draw_lab`, :class:`LabDraw`)
and each experiment's (:class:`ExperimentDraw`). C-arm (LPS) mm for points, transducer frame for the
bubble offset (docs/error-budget.md, "The sources").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from histostudy.geometry import make_transform, matrix_from_rotvec
from histostudy.imaging import View
from histostudy.imaging.carm_errors import GRAVITY_CARM, displaced_view, miscalibrated_view
from histostudy.transducer import ManufacturingDeviation, TransducerModel

from ..targeting.robots import KinematicError
from ._magnitudes import (
    ISO_2768_M_DEVIATION,
    AnnotationError,
    BubbleOffset,
    CarmReproducibility,
    GantrySag,
    PhantomMotion,
    ProjectionError,
    RegistrationError,
    RobotAccuracy,
    RobotRepeatability,
    TransducerReplacement,
)

__all__ = ["ExperimentDraw", "LAB_SOURCES", "LabDraw", "LabErrorModel", "draw_lab"]

#: The sources, in the order of :class:`LabErrorModel`'s fields and of their seed streams (a new
#: source is appended, so that no existing stream moves).
LAB_SOURCES = ("manufacturing", "bubble_offset", "projection", "gantry_sag", "registration", "annotation", "robot",
               "phantom_motion", "replacement", "carm_reproducibility", "robot_accuracy")

_SOURCE_TYPES = {"manufacturing": ManufacturingDeviation, "bubble_offset": BubbleOffset,
                 "projection": ProjectionError, "gantry_sag": GantrySag, "registration": RegistrationError,
                 "annotation": AnnotationError, "robot": RobotRepeatability, "phantom_motion": PhantomMotion,
                 "replacement": TransducerReplacement, "carm_reproducibility": CarmReproducibility,
                 "robot_accuracy": RobotAccuracy}


@dataclass(frozen=True)
class LabErrorModel:
    """The lab's error sources (§IV): one field per source, ``None`` = off (docs/error-budget.md,
    "The sources", says where each acts and where each default comes from).

    ``LabErrorModel()`` is the lab with every source at its documented default; :meth:`off` is the
    study as notebooks 04 and 05 run it; :meth:`only` and :meth:`without` toggle one source and keep
    the others' magnitudes.

    Args:
        manufacturing: the physical transducer's tolerances (default ISO 2768-1 class m).
        bubble_offset: the bubble cloud's offset from the physical focal point, per lab.
        projection: the C-arm's geometric calibration error, per plane.
        gantry_sag: each plane's displacement along gravity.
        registration: the CBCT-to-fluoroscopy registration error, per experiment.
        annotation: the observer's segmentation of the treated zone, per experiment.
        robot: the UR5e's landing noise.
        phantom_motion: the phantom's shift before the post-treatment CBCT, per experiment.
        replacement: the bubble offset's change between experiments (the transducer re-placed).
        carm_reproducibility: each acquisition's projection shift on the detector.
        robot_accuracy: the arm's kinematic error against its nominal table, per lab.

    Raises:
        TypeError: a field neither None nor its magnitude dataclass.
    """

    manufacturing: ManufacturingDeviation | None = ISO_2768_M_DEVIATION
    bubble_offset: BubbleOffset | None = BubbleOffset()
    projection: ProjectionError | None = ProjectionError()
    gantry_sag: GantrySag | None = GantrySag()
    registration: RegistrationError | None = RegistrationError()
    annotation: AnnotationError | None = AnnotationError()
    robot: RobotRepeatability | None = RobotRepeatability()
    phantom_motion: PhantomMotion | None = PhantomMotion()
    replacement: TransducerReplacement | None = TransducerReplacement()
    carm_reproducibility: CarmReproducibility | None = CarmReproducibility()
    robot_accuracy: RobotAccuracy | None = RobotAccuracy()

    def __post_init__(self):
        for name, kind in _SOURCE_TYPES.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                raise TypeError(f"LabErrorModel.{name} must be a {kind.__name__} or None (off), got {value!r}")

    @property
    def enabled(self) -> tuple[str, ...]:
        """The sources that are on, in :data:`LAB_SOURCES` order."""
        return tuple(name for name in LAB_SOURCES if getattr(self, name) is not None)

    @staticmethod
    def _check_name(name: str) -> None:
        if name not in LAB_SOURCES:
            raise ValueError(f"source must be one of {LAB_SOURCES}, got {name!r}")

    def off(self) -> LabErrorModel:
        """Every source off: the studies as they run without a lab model."""
        return dataclasses.replace(self, **{name: None for name in LAB_SOURCES})

    def only(self, name: str) -> LabErrorModel:
        """This model with every source but ``name`` off."""
        self._check_name(name)
        return dataclasses.replace(self.off(), **{name: getattr(self, name)})

    def without(self, name: str) -> LabErrorModel:
        """This model with ``name`` off."""
        self._check_name(name)
        return dataclasses.replace(self, **{name: None})

    def describe(self) -> list[dict]:
        """One row per source: its name, whether it is on, and its magnitudes."""
        rows = []
        for name in LAB_SOURCES:
            value = getattr(self, name) or getattr(LabErrorModel(), name)
            rows.append({"source": name, "on": getattr(self, name) is not None,
                         "magnitudes": ", ".join(f"{f.name} = {getattr(value, f.name)!r}".replace("(", "").replace(")",
                                                                                                                   "")
                                                 for f in dataclasses.fields(value)
                                                 if not f.name.startswith("extra_screw"))})
        return rows


def _stream(seq: np.random.SeedSequence, *keys: int) -> np.random.Generator:
    """A generator on ``seq``'s child at ``keys`` (stateless: the same keys give the same draws)."""
    return np.random.default_rng(np.random.SeedSequence(seq.entropy, spawn_key=tuple(seq.spawn_key) + tuple(keys)))


@dataclass(frozen=True, eq=False)
class ExperimentDraw:
    """The per-experiment draws (zeros where the source is off): ``T_cbct_carm`` (the CBCT's
    coordinates of a C-arm point, 4x4 mm), the annotation's centroid offset (3, mm) and radius
    errors per direction (depth, TB, LR; mm), the phantom's motion (3, mm, C-arm frame), and the
    re-placed transducer's bubble-offset change (3, mm, transducer frame)."""

    T_cbct_carm: np.ndarray
    annotation_centroid_mm: np.ndarray
    annotation_radius_mm: np.ndarray
    phantom_motion_mm: np.ndarray
    bubble_offset_change_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def measured_point(self, point_mm) -> np.ndarray:
        """Where the lab reads a treated zone's centroid at ``point_mm`` (C-arm frame) in its
        post-treatment CBCT: moved with the phantom, read through the registration, annotated."""
        p = np.asarray(point_mm, float) + self.phantom_motion_mm
        return self.T_cbct_carm[:3, :3] @ p + self.T_cbct_carm[:3, 3] + self.annotation_centroid_mm

    def read_target(self, target_mm) -> np.ndarray:
        """The target's coordinates as read from the pre-treatment CBCT (through the registration)."""
        return self.T_cbct_carm[:3, :3] @ np.asarray(target_mm, float) + self.T_cbct_carm[:3, 3]


@dataclass(frozen=True, eq=False)
class LabDraw:
    """One lab's realisation of a :class:`LabErrorModel` (its systematic sources), and its
    per-experiment draws (:meth:`experiment`). Each source draws from its own stream, so turning
    one off changes no other's numbers (:meth:`variant` is :func:`draw_lab` of a sub-model).

    ``physical``: the transducer the frames show (the study's where ``manufacturing`` is off);
    ``bubble_offset_mm``: transducer frame (x, y, z), zeros when off; ``frame_views``: the true
    geometry (gantry sag); ``estimator_views``: what the estimator is given (the calibration,
    with its error). ``study_physical`` / ``study_views``: the study's, for the sources off.
    """

    model: LabErrorModel
    seed: np.random.SeedSequence
    physical: TransducerModel
    bubble_offset_mm: np.ndarray
    frame_views: tuple
    estimator_views: tuple
    study_physical: TransducerModel
    study_views: tuple

    def variant(self, model: LabErrorModel) -> LabDraw:
        """This lab with only ``model``'s sources on: each must be on here with the same
        magnitudes. The same numbers as :func:`draw_lab` of ``model`` on this seed, without
        drawing the transducer again."""
        if not isinstance(model, LabErrorModel):
            raise TypeError(f"model must be a LabErrorModel, got {type(model).__name__}")
        for name in model.enabled:
            if getattr(model, name) != getattr(self.model, name):
                raise ValueError(f"model.{name} = {getattr(model, name)!r} is not this lab's "
                                 f"({getattr(self.model, name)!r}): draw that lab with draw_lab")
        on = set(model.enabled)
        return LabDraw(model, self.seed,
                       self.physical if "manufacturing" in on else self.study_physical,
                       self.bubble_offset_mm if "bubble_offset" in on else np.zeros(3),
                       self.frame_views if "gantry_sag" in on else self.study_views,
                       self.estimator_views if "projection" in on else self.study_views,
                       self.study_physical, self.study_views)

    def robot_repeatability_mm(self, study_value: float) -> float:
        """The robot's landing noise SD: the lab's where the source is on, else the study's."""
        return study_value if self.model.robot is None else self.model.robot.sd_mm

    def experiment(self, index: int) -> ExperimentDraw:
        """The per-experiment draws of experiment ``index`` (the same for every configuration)."""
        m = self.model
        rng_reg = _stream(self.seed, LAB_SOURCES.index("registration"), int(index))
        t, w = rng_reg.normal(0.0, 1.0, 3), rng_reg.normal(0.0, 1.0, 3)
        T = np.eye(4)
        if m.registration is not None:
            T = make_transform(matrix_from_rotvec(np.radians(m.registration.rotation_deg) * w),
                               m.registration.translation_mm * t)
        rng_ann = _stream(self.seed, LAB_SOURCES.index("annotation"), int(index))
        c, r = rng_ann.normal(0.0, 1.0, 3), rng_ann.normal(0.0, 1.0, 3)
        ann = (np.zeros(3), np.zeros(3)) if m.annotation is None else \
            (m.annotation.centroid_mm * c, m.annotation.radius_mm * r)
        rng_mot = _stream(self.seed, LAB_SOURCES.index("phantom_motion"), int(index))
        motion = rng_mot.normal(0.0, 1.0, 3)
        motion = np.zeros(3) if m.phantom_motion is None else m.phantom_motion.sd_mm * motion
        change = _stream(self.seed, LAB_SOURCES.index("replacement"), int(index)).normal(0.0, 1.0, 3)
        change = np.zeros(3) if m.replacement is None else np.asarray(m.replacement.sd_mm) * change
        return ExperimentDraw(T, ann[0], ann[1], motion, change)

    def bubble_offset_at(self, index: int) -> np.ndarray:
        """The bubble cloud's offset in experiment ``index`` (transducer frame, mm): the lab's,
        changed by the re-placed transducer's draw where ``replacement`` is on."""
        if self.model.replacement is None:
            return self.bubble_offset_mm
        return self.bubble_offset_mm + self.experiment(index).bubble_offset_change_mm

    def acquisition_views(self, experiment: int, acquisition: int, views) -> tuple:
        """The views the estimator is told for acquisition ``acquisition`` of experiment
        ``experiment``: ``views`` (the lab's calibration), each plane's projection shifted by
        ``carm_reproducibility`` (mm at the detector, one draw per plane); ``views`` unchanged
        where the source is off."""
        m = self.model.carm_reproducibility
        if m is None:
            return tuple(views)
        rng = _stream(self.seed, LAB_SOURCES.index("carm_reproducibility"), int(experiment), int(acquisition))
        return tuple(miscalibrated_view(v, detector_shift_px=m.shift_mm * rng.normal(0.0, 1.0, 2) / v.pixel_mm)
                     for v in views)

    def kinematic_error(self) -> KinematicError | None:
        """The lab's arm against its nominal DH table (``robot_accuracy``; one draw per lab), or
        None where the source is off."""
        m = self.model.robot_accuracy
        if m is None:
            return None
        normals = _stream(self.seed, LAB_SOURCES.index("robot_accuracy")).normal(0.0, 1.0, (4, 6))
        return KinematicError.from_normals(normals, length_sd_mm=m.length_sd_mm, angle_sd_rad=m.angle_sd_rad)


def draw_lab(model: LabErrorModel, seed, *, physical: TransducerModel, views,
             physical_seed: np.random.SeedSequence | int | None = None) -> LabDraw:
    """Draw one lab of ``model``: its systematic sources once (each from its own stream, standard
    normals scaled by the magnitudes, so a magnitude changes no other draw).

    Args:
        model: the lab error model.
        seed: the lab's seed (an int or a ``SeedSequence``).
        physical: the study's physical transducer, used where ``manufacturing`` is off (and whose spec
            and spacing the lab's transducer takes where it is on).
        views: the study's calibrated views, used where the view sources are off.
        physical_seed: the seed the study drew its transducer from (the same quadrants moved by the
            lab's tolerances); None: the lab's own stream.

    Returns:
        The :class:`LabDraw`.

    Raises:
        TypeError: ``model`` not a LabErrorModel, or ``physical`` not a TransducerModel.
        ValueError: ``views`` empty or not View objects.
    """
    if not isinstance(model, LabErrorModel):
        raise TypeError(f"model must be a LabErrorModel, got {type(model).__name__}")
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    if not isinstance(physical, TransducerModel):
        raise TypeError(f"physical must be a TransducerModel, got {type(physical).__name__}")
    views = tuple(views)
    if not views or not all(isinstance(v, View) for v in views):
        raise ValueError(f"views must be a non-empty sequence of View, got {views!r}")
    study_physical = physical
    if model.manufacturing is not None:
        rng = _stream(seq, LAB_SOURCES.index("manufacturing")) if physical_seed is None \
            else np.random.default_rng(physical_seed)
        physical = TransducerModel.build_physical(physical.spec, physical.spacing_mm, deviation=model.manufacturing,
                                                  rng=rng)
    offset = _stream(seq, LAB_SOURCES.index("bubble_offset")).normal(0.0, 1.0, 3)
    offset = np.zeros(3) if model.bubble_offset is None else np.asarray(model.bubble_offset.sd_mm) * offset
    rng_proj = _stream(seq, LAB_SOURCES.index("projection"))
    rng_sag = _stream(seq, LAB_SOURCES.index("gantry_sag"))
    frame_views, estimator_views = [], []
    for v in views:
        source, shift = rng_proj.normal(0.0, 1.0, 3), rng_proj.normal(0.0, 1.0, 2)
        sag = rng_sag.normal(0.0, 1.0)
        estimator_views.append(v if model.projection is None else miscalibrated_view(
            v, source_offset_mm=model.projection.source_mm * source,
            detector_shift_px=model.projection.reprojection_px * shift))
        frame_views.append(v if model.gantry_sag is None else displaced_view(
            v, make_transform(None, model.gantry_sag.sd_mm * sag * GRAVITY_CARM)))
    return LabDraw(model, seq, physical, offset, tuple(frame_views), tuple(estimator_views), study_physical, views)
