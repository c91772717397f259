"""What notebook 04's pose-estimation study runs: its parameters and its segmentation/orientation stages.

:class:`PoseSectionConfig` holds the notebook's parameters as the profiles name them;
:class:`PoseStudyConfig`, the experiment's parameters (§II-D: the number of phantom
experiments, the treatment radii ``r`` in mm, the rendering of §II-B.2, the refinement modes of
§II-B.3 and the distance maps of eq. 3); :func:`study_stages` picks the segmenter (§II-B.2) and the
orientation source (§II-B.4, eq. 4) the estimates run on: the shipped learned networks where
their validation figures meet :data:`histostudy.pose.LEARNED_STAGE_REQUIREMENTS`, the oracles
otherwise. Lengths in mm, angles in degrees where a name says ``deg``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from histostudy.imaging import FrameRenderConfig
from histostudy.learning import OracleOrientation, OracleSegmenter, OrientationSource, Segmenter
from histostudy.pose import MAP_KINDS, learned_stage_shortfalls

from ..section import RenderedSectionConfig

__all__ = ["PoseSectionConfig", "PoseStudyConfig", "StudyStages", "study_stages"]


@dataclass(frozen=True)
class PoseStudyConfig(FrameRenderConfig):
    """Parameters of the pose-estimation study (defaults: the standard profile's).

    The rendering (``photons_per_pixel``, ``n_splats``, ``splat_sigma_mm``, §II-B.2, and the
    ``background`` behind the transducer, the paper's pose studies: agarose phantoms) is the
    shared :class:`~histostudy.imaging.FrameRenderConfig`, checks included.

    Attributes:
        n_experiments: phantom experiments (paper: 10).
        margin_mm: radii drawn per experiment (paper: 10 or 12.5 mm, spheres of 2.0 or 2.5 cm).
        degradation: ``"table1"`` (oracle errs as the paper's U-Net, Table I) or ``"none"``.
        modes: refinement modes to run on the same frames (``"paper"``, ``"fast"``).
        distance_maps: map kinds to run on the same frames (``"occlusion_aware"``, ``"per_class"``,
            see :func:`histostudy.pose.estimate_pose`); every mode runs with every kind.
        track: also re-estimate each margin pose warm-started from the centre's estimate (fast
            mode), as live tracking of a 10-12.5 mm move would.
        tilt_sd_deg: tilt of the transducer axis from vertical (anterior-posterior), per axis.
        focal_jitter_mm: focal point uniform within ± this of the phantom centre, per axis.
        robot_repeatability_mm: SD of the robot's positioning noise (UR5e: ±0.03 mm).
        bubble_offset_mm: offset of the bubble cloud from the acoustic focal point, transducer frame.
        assumed_bubble_offset_mm: the offset the prediction adds to the estimated focal point
            (transducer frame); None: ``bubble_offset_mm``, known as after a test pulse. A lab
            that did not calibrate it (:class:`~histostudy.study.budget._sources.LabErrorModel`)
            assumes zeros.
    """

    n_experiments: int = 10
    margin_mm: tuple = (10.0, 12.5)
    degradation: str = "table1"
    modes: tuple = ("paper", "fast")
    distance_maps: tuple = ("occlusion_aware",)
    track: bool = True
    tilt_sd_deg: float = 10.0
    focal_jitter_mm: float = 5.0
    robot_repeatability_mm: float = 0.01
    bubble_offset_mm: tuple = (0.0, 0.0, 0.0)
    assumed_bubble_offset_mm: tuple | None = None

    def __post_init__(self):
        super().__post_init__()
        for name in ("bubble_offset_mm", "assumed_bubble_offset_mm"):
            value = getattr(self, name)
            if value is not None and (np.shape(value) != (3,) or not np.all(np.isfinite(np.asarray(value, float)))):
                raise ValueError(f"{name} must be 3 finite numbers (transducer frame, mm), got {value!r}")
        if self.n_experiments < 1:
            raise ValueError(f"n_experiments must be >= 1, got {self.n_experiments!r}")
        if not self.margin_mm or any(not (np.isfinite(r) and r > 0) for r in self.margin_mm):
            raise ValueError(f"margin_mm must hold positive radii in mm, got {self.margin_mm!r}")
        OracleSegmenter.named(self.degradation)  # a clear error now for an unknown name
        if not self.modes or any(m not in ("paper", "fast") for m in self.modes):
            raise ValueError(f"modes must be a non-empty subset of ('paper', 'fast'), got {self.modes!r}")
        if not self.distance_maps or any(m not in MAP_KINDS for m in self.distance_maps):
            raise ValueError(f"distance_maps must be a non-empty subset of {MAP_KINDS}, got {self.distance_maps!r}")

    @property
    def variants(self) -> list[tuple[str, str]]:
        """Every (mode, distance-map kind) pair the study runs on each pair of frames."""
        return [(mode, maps) for mode in self.modes for maps in self.distance_maps]

    def segmenter(self) -> OracleSegmenter:
        """The oracle segmenter of ``degradation``."""
        return OracleSegmenter.named(self.degradation)

    @property
    def predicted_bubble_offset_mm(self) -> np.ndarray:
        """The offset the prediction adds to the estimated focal point (transducer frame, mm)."""
        offset = self.bubble_offset_mm if self.assumed_bubble_offset_mm is None else self.assumed_bubble_offset_mm
        return np.asarray(offset, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class StudyStages:
    """The segmenter and orientation source a pose study runs on, and why those (:func:`study_stages`).

    ``shipped_segmenter`` / ``shipped_orientation`` are the learned networks that were considered
    (None when missing or not asked for), whether or not the study runs on them.
    """

    segmenter: Segmenter
    orientation: OrientationSource
    learned: bool
    why: str
    shipped_segmenter: Segmenter | None = None
    shipped_orientation: OrientationSource | None = None


def study_stages(config, learned: bool = True, *, segmenter=None, orientation=None) -> StudyStages:
    """The stages of a study's pose estimates: learned by default, the oracles where the learned ones
    fall short. ``config``: a :class:`PoseStudyConfig` or any study config with a ``segmenter()``
    giving its oracle (notebook 05's :class:`~histostudy.study.targeting.TargetingStudyConfig`).

    With ``learned``, the shipped U-Net and VGG19 (:func:`histostudy.learning.segment.default_segmenter`,
    :func:`histostudy.pose.conic_orientation.default_orientation`, or the ``segmenter`` / ``orientation``
    given) when their manifests meet :data:`histostudy.pose.LEARNED_STAGE_REQUIREMENTS`;
    otherwise, or without ``learned``, the config's oracles (Table I degradation, the paper's
    angle MAE). ``why`` says which and why, for the report.
    """
    oracles = (config.segmenter(), OracleOrientation())
    if not learned:
        return StudyStages(*oracles, learned=False, why="oracle stages: the learned stages are disabled "
                           "(learned_stages = False)")
    if segmenter is None or orientation is None:
        from histostudy.learning import default_segmenter
        from histostudy.pose import default_orientation

        segmenter = default_segmenter() if segmenter is None else segmenter
        orientation = default_orientation() if orientation is None else orientation
    shipped = dict(shipped_segmenter=segmenter, shipped_orientation=orientation)
    shortfalls = learned_stage_shortfalls(segmenter, orientation)
    if shortfalls:
        return StudyStages(*oracles, learned=False, why="oracle stages (Table I degradation, the paper's angle "
                           "MAE), because " + "; ".join(shortfalls), **shipped)
    names = [(getattr(stage, "manifest", None) or {}).get("weights_file", type(stage).__name__)
             for stage in (segmenter, orientation)]
    if getattr(orientation, "fallback", None) is not None:  # the geometric initialiser
        orientation_text = f"the inner-boundary conic initialiser (VGG19 {names[1]} where it finds no ellipse)"
    else:
        orientation_text = f"the VGG19 {names[1]}"
    return StudyStages(segmenter, orientation, learned=True,
                       why=f"learned stages: the U-Net {names[0]} and {orientation_text}", **shipped)


@dataclass(frozen=True)
class PoseSectionConfig(RenderedSectionConfig):
    """Notebook 04's parameters, as the profiles (``histostudy/reporting/profiles/*.toml``) name them.

    Rendering: ``photons_per_pixel``, ``n_splats``, ``splat_sigma_mm``; model grids
    ``pose_spacing_mm`` (the digital model of the cost) and ``render_spacing_mm`` (the rendered and
    the physical transducer). The experiments: ``background``, ``n_experiments``, ``margin_mm``
    (radii ``r``), ``modes``, ``distance_maps``, ``degradation`` (see :class:`PoseStudyConfig`). The
    sweeps: ``robustness_poses``, ``robustness_vgg19`` (also the VGG19 alone as orientation),
    ``degradation_levels`` / ``degradation_poses``, ``noise_photons`` / ``noise_poses``. The learned
    stages: ``learned_stages`` (run on them where they qualify) and ``learned_experiments`` (the
    experiments the other stages also run). The CBCT reference: ``cbct_reference``,
    ``phantom_voxel_mm``, ``cbct_voxel_mm``. The RTK projector: ``independent_projector``,
    ``projector_study_poses``, ``projector_random_poses``.
    """

    NOTEBOOK = "04"

    n_experiments: int
    margin_mm: list
    modes: list
    distance_maps: list
    degradation: str
    robustness_poses: int
    degradation_levels: list
    degradation_poses: int
    learned_stages: bool
    learned_experiments: int
    noise_photons: list
    noise_poses: int
    cbct_reference: bool
    phantom_voxel_mm: float
    cbct_voxel_mm: float
    robustness_vgg19: bool
    independent_projector: bool
    projector_study_poses: int
    projector_random_poses: int

    def study_config(self) -> PoseStudyConfig:
        """The :class:`PoseStudyConfig` of these parameters (the rest keep its defaults)."""
        return PoseStudyConfig(
            n_experiments=self.n_experiments, margin_mm=tuple(self.margin_mm), background=self.background,
            photons_per_pixel=self.photons_per_pixel, n_splats=self.n_splats, splat_sigma_mm=self.splat_sigma_mm,
            degradation=self.degradation, modes=tuple(self.modes), distance_maps=tuple(self.distance_maps))

# the 0.1.0 name, deprecated (CHANGELOG.md)
