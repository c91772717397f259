"""The magnitudes of the lab's error sources (§IV): one frozen dataclass per source of
:class:`~histostudy.study.budget.LabErrorModel`, every field a documented SD (lengths in mm, the
frame named per field; angles in degrees where named). Where each default comes from:
:data:`~histostudy.study.budget.SOURCE_REFERENCES`; none was fitted to the paper's figures.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from histostudy.transducer import ManufacturingDeviation

__all__ = ["AnnotationError", "BubbleOffset", "CarmReproducibility", "GantrySag", "ISO_2768_M_DEVIATION",
           "PhantomMotion", "ProjectionError", "RegistrationError", "RobotAccuracy", "RobotRepeatability",
           "TransducerReplacement"]


class _Magnitudes:
    """A source's magnitudes: every field a finite number >= 0 (or a tuple of them), checked and
    made float when the dataclass is built."""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            values = value if isinstance(value, tuple) else (value,)
            for v in values:
                if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                        or not math.isfinite(float(v)) or float(v) < 0:
                    raise ValueError(f"{type(self).__name__}.{f.name} must be finite and >= 0, got {value!r}")
            object.__setattr__(self, f.name, tuple(float(v) for v in values) if isinstance(value,
                                                                                           tuple) else float(value))


@dataclass(frozen=True)
class BubbleOffset(_Magnitudes):
    """SD of the bubble cloud's offset from the physical focal point, per transducer axis (mm;
    LR, TB, depth). One offset per transducer: it is systematic, a bias.

    Default (0.5, 0.5, 1.0) mm: an assumption scaled to the cloud (§II-C: 3 x 3 x 6 mm), a sixth
    of its extent per axis. The clinical workflow calibrates this offset with a test pulse
    (§I, step 3) because it is not negligible; the paper's C-arm targeting did not.

    Args:
        sd_mm: the SDs (LR, TB, depth; mm).

    Raises:
        ValueError: a field not finite and >= 0, or not 3 SDs.
    """

    sd_mm: tuple = (0.5, 0.5, 1.0)

    def __post_init__(self):
        if np.shape(self.sd_mm) != (3,):
            raise ValueError(f"BubbleOffset.sd_mm must be 3 SDs (LR, TB, depth) in mm, got {self.sd_mm!r}")
        object.__setattr__(self, "sd_mm", tuple(self.sd_mm))
        super().__post_init__()


@dataclass(frozen=True)
class ProjectionError(_Magnitudes):
    """The C-arm's geometric calibration error, one draw per plane: the principal point off by
    ``reprojection_px`` (SD per detector axis) and the source off by ``source_mm`` (SD per world
    axis), the detector where the calibration says.

    Defaults: 0.5 px (0.15 mm at the 0.308 mm detector pixel), the order of the residual
    reprojection error of phantom-based C-arm calibrations; 1.0 mm for the focal spot, the
    order of its size. Both are assumptions, stated as such.

    Args:
        reprojection_px: the principal point's SD per detector axis (px).
        source_mm: the source's SD per world axis (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    reprojection_px: float = 0.5
    source_mm: float = 1.0


@dataclass(frozen=True)
class GantrySag(_Magnitudes):
    """Each plane's source-detector assembly displaced along gravity (SD, mm), one draw per plane:
    what the geometric calibration did not capture at the fluoroscopy's angulation.

    Default 0.5 mm: an assumption, a fraction of the millimetre-scale flexing that C-arm gantries
    show over an orbit (which their calibration captures for the CBCT orbit, not for each
    fluoroscopic angulation of a biplane pair).

    Args:
        sd_mm: the displacement's SD along gravity (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    sd_mm: float = 0.5


@dataclass(frozen=True)
class RegistrationError(_Magnitudes):
    """The CBCT's coordinates against the fluoroscopy's: a rigid error, per experiment (SD of each
    translation axis in mm, of each rotation-vector component in degrees).

    Defaults 0.3 mm and 0.1 deg: assumptions of a same-C-arm registration (the CBCT is
    reconstructed in the frame of the C-arm's calibration; what differs is its reproducibility).

    Args:
        translation_mm: SD of each translation axis (mm).
        rotation_deg: SD of each rotation-vector component (deg).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    translation_mm: float = 0.3
    rotation_deg: float = 0.1


@dataclass(frozen=True)
class AnnotationError(_Magnitudes):
    """The observer's segmentation of the treated zone (per experiment): centroid SD per axis and
    radius SD per direction (mm).

    Defaults 0.41 mm: derived, not fitted. A sphere annotated by hand in a CBCT of 1 mm voxels
    (the studies' reconstruction) has each of its six extreme points placed within ±1 voxel
    (uniform, SD 1/√3 mm); a centroid or radius is half the sum or difference of two of them:
    SD (1/√3)/√2 = 0.41 mm.

    Args:
        centroid_mm: the centroid's SD per axis (mm).
        radius_mm: the radius' SD per direction (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    centroid_mm: float = 0.41
    radius_mm: float = 0.41


@dataclass(frozen=True)
class RobotRepeatability(_Magnitudes):
    """The UR5e's landing noise, SD per axis (mm). Default 0.03 mm: the paper's ±0.03 mm pose
    repeatability (§II-C, the UR5e's data sheet) taken as one SD, the conservative reading.

    Args:
        sd_mm: the landing noise's SD per axis (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    sd_mm: float = 0.03


@dataclass(frozen=True)
class PhantomMotion(_Magnitudes):
    """The phantom's shift between the treatment and the post-treatment CBCT (SD per axis, mm; per
    experiment). Default 0.2 mm: an assumption for an agarose phantom in a water bath as the
    transducer is lifted out of it.

    Args:
        sd_mm: the shift's SD per axis (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    sd_mm: float = 0.2


#: The manufacturing tolerances of the lab model: ISO 2768-1 class m ("medium") for the quadrants'
#: placement in a 120-400 mm housing, ±0.5 mm and ±0°10', read as uniform (SD = tolerance / √3).
ISO_2768_M_DEVIATION = ManufacturingDeviation(quadrant_offset_sd_mm=0.5 / math.sqrt(3),
                                              quadrant_tilt_sd_deg=(10.0 / 60.0) / math.sqrt(3))


@dataclass(frozen=True)
class TransducerReplacement(_Magnitudes):
    """The bubble cloud's offset from the physical focal point varying between experiments, SD per
    transducer axis (mm; LR, TB, depth), one draw per experiment about the lab's
    :class:`BubbleOffset`: the transducer lifted out of the water bath, re-attached or re-coupled,
    a new phantom in the acoustic path. Unknown to the estimator; it moves the treated zone.

    Default 0.39 mm per axis: derived. Minesinger et al. (J Appl Clin Med Phys 2025) re-attached the
    transducer before each of 8 treatments of one user and day and measured the short-axis targeting
    error's SD, 0.60 mm; less this model's other per-experiment sources acting on a zone's centroid
    (annotation 0.41 mm, phantom motion 0.2 mm, robot 0.03 mm) in quadrature, 0.39 mm remains. The
    registration's share is not subtracted (an upper reading); their second day's SD (0.18 mm) would
    leave nothing, so the source is also swept over 0-0.6 mm (``_references``).

    Args:
        sd_mm: the SDs (LR, TB, depth; mm).

    Raises:
        ValueError: a field not finite and >= 0, or not 3 SDs.
    """

    sd_mm: tuple = (0.39, 0.39, 0.39)

    def __post_init__(self):
        if np.shape(self.sd_mm) != (3,):
            raise ValueError(f"TransducerReplacement.sd_mm must be 3 SDs (LR, TB, depth) in mm, got {self.sd_mm!r}")
        object.__setattr__(self, "sd_mm", tuple(self.sd_mm))
        super().__post_init__()


@dataclass(frozen=True)
class CarmReproducibility(_Magnitudes):
    """Each acquisition's projection shifted on the detector against the calibration (SD per
    detector axis, mm at the detector), one draw per acquisition and plane: a gantry that returns to
    its angles reproduces its geometry only to this. It acts on the views the estimator is told
    (the frames keep the true geometry and stay shareable between labs).

    Default 0.1 mm: cited. Fahrig & Holdsworth (Med Phys 2000) found a C-arm gantry's motion
    reproducible within one day to a mean SD of 0.11 mm (tangential) and 0.08 mm (axial).

    Args:
        shift_mm: the shift's SD per detector axis (mm at the detector).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    shift_mm: float = 0.1


#: The RMS TCP position error (mm) of a UR5e whose DH lengths err by 1 mm SD and whose DH angles
#: and joint zero offsets err by 1/500 rad SD, the TCP 250 mm below the flange, over joint
#: configurations within ±0.5 rad of HOME_JOINTS_RAD: derived by Monte Carlo (400 arms x 10
#: configurations), rechecked independently by the tests. Scales :class:`RobotAccuracy`'s draws.
RMS_TCP_MM_PER_UNIT_DH_ERROR = 4.3

#: The arm length (mm) that turns a DH length error into the angle error drawn with it.
DH_ANGLE_LENGTH_MM = 500.0


@dataclass(frozen=True)
class RobotAccuracy(_Magnitudes):
    """The arm's absolute position accuracy: the RMS distance (mm) between the commanded and the
    reached TCP over its working poses, one arm per lab (a bias of the poses, not a noise). The
    arm's true DH parameters differ from the nominal table its controller inverts: every length
    (d, a) by ``length_sd_mm`` and every angle (alpha, joint zero offset) by ``angle_sd_rad``, so
    that the RMS TCP error is ``position_mm``. A move to a new target and the hand-eye calibration's
    poses see it; repeatability (:class:`RobotRepeatability`) is the scatter about it.

    Default 0.65 mm: the linear position accuracy of an uncalibrated six-axis arm whose
    repeatability is 37 µm (Slamani et al., Industrial Robot 2012; an ABB IRB 1600): no UR5e
    measurement is cited, so the source is swept (``_references``).

    Args:
        position_mm: the RMS TCP position error over the working poses (mm).

    Raises:
        ValueError: a field not finite and >= 0.
    """

    position_mm: float = 0.65

    @property
    def length_sd_mm(self) -> float:
        """SD of each DH length error (mm)."""
        return self.position_mm / RMS_TCP_MM_PER_UNIT_DH_ERROR

    @property
    def angle_sd_rad(self) -> float:
        """SD of each DH angle and joint zero-offset error (rad)."""
        return self.length_sd_mm / DH_ANGLE_LENGTH_MM
