"""Where every magnitude of the lab's error sources comes from (§IV): per source its default value,
range, reference, mapping and status (``cited``, ``derived``, ``swept``), and a source or a model
built at another magnitude (docs/error-budget.md, "The sources").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ._sources import LAB_SOURCES, LabErrorModel

__all__ = ["SOURCE_REFERENCES", "STATUSES", "SourceReference", "magnitudes_at", "model_at", "references_table",
           "sweep_values"]

#: The statuses a reference can have (module docstring).
STATUSES = ("cited", "derived", "swept")

#: A mean 3D Euclidean error over an isotropic normal error is 2 sqrt(2/pi) = 1.596 per-axis SDs;
#: a mean 2D distance sqrt(pi/2) = 1.253.
_MEAN_3D_PER_SD, _MEAN_2D_PER_SD = 2.0 * math.sqrt(2.0 / math.pi), math.sqrt(math.pi / 2.0)


@dataclass(frozen=True)
class SourceReference:
    """One source's magnitude and where it comes from (module docstring); ``fields``: the
    magnitude dataclass's fields that :func:`magnitudes_at` scales."""

    source: str
    value: float
    unit: str
    low: float
    high: float
    reference: str
    doi: str
    mapping: str
    status: str
    checked: str
    fields: tuple

    def __post_init__(self):
        if self.status not in STATUSES:
            raise ValueError(f"{self.source}: status must be one of {STATUSES}, got {self.status!r}")
        if not 0.0 <= self.low <= self.value <= self.high:
            raise ValueError(f"{self.source}: expected 0 <= low <= value <= high, got {self.low}, {self.value}, "
                             f"{self.high}")

    @property
    def provenance(self) -> str:
        """One line for a sources table: status, value, range and the reference."""
        return (f"{self.status}: {self.value:g} {self.unit} (range {self.low:g}-{self.high:g}); "
                f"{self.reference}" + (f", doi:{self.doi}" if self.doi else ""))


def _ref(source, value, unit, low, high, reference, doi, mapping, status, checked, fields) -> SourceReference:
    return SourceReference(source, float(value), unit, float(low), float(high), reference, doi, mapping, status,
                           checked, tuple(fields))


_ISO = ("ISO 2768-1:1989, general tolerances for linear and angular dimensions", "",
        "each quadrant's rigid offset SD per axis = tolerance / sqrt(3) (uniform), its tilt SD = angular tolerance "
        "/ sqrt(3); class m for a 120-400 mm part: +-0.5 mm, +-0 deg 10'. The range runs from class f (+-0.2 mm) to "
        "class c (+-1.2 mm)")

#: The references, one per source of LAB_SOURCES, in its order.
SOURCE_REFERENCES = {r.source: r for r in (
    _ref("manufacturing", 0.5 / math.sqrt(3), "mm (quadrant offset SD per axis)", 0.2 / math.sqrt(3),
         1.2 / math.sqrt(3), *_ISO, "swept",
         "the standard's table (linear: f 0.2, m 0.5, c 1.2 mm for 120-400 mm; angular +-0 deg 10' for f and m): "
         "confirmed; the class the transducer's housing was made to is not published",
         ("quadrant_offset_sd_mm", "quadrant_tilt_sd_deg")),
    _ref("bubble_offset", 1.0, "mm (SD along depth; LR and TB half of it)", 0.0, 2.0,
         "Kutlu, Minesinger, Laeseke, Speidel, Wagner. J Appl Clin Med Phys 2024", "10.1002/acm2.14329",
         "one offset per lab (transducer frame); Kutlu et al. measured a 2 mm offset along the propagation direction "
         "in six CBCT-guided phantom treatments: one system's offset, i.e. one draw, 2 SD at the default. The paper's "
         "own depth bias (0.0 mm) is another draw",
         "swept", "abstract: 'a 2 mm offset in the direction of ultrasound propagation (Z) was measured': confirmed; "
                  "no spread across transducers is given", ("sd_mm",)),
    _ref("projection", 0.5, "px (principal point SD per detector axis; the source SD scales with it, 1 mm at 0.5 px)",
         0.25,
         0.73 / _MEAN_2D_PER_SD / 0.308,
         "Ouadah, Stayman, Gang, Ehtiati, Siewerdsen. Phys Med Biol 2016 (PMC4948745)", "",
         "a reprojection error (RPE) is a mean 2D distance: per-axis SD = RPE / sqrt(pi/2); Ouadah et al.'s 0.73 mm "
         "(conventional calibration, Artis Zeego) gives 0.58 mm, 1.9 px of 0.308 mm if read at the detector; their "
         "self-calibration's 0.55 mm, 1.4 px. The default (0.15 mm) is a better calibration than theirs",
         "swept", "abstract: RPE 0.73 mm conventional vs 0.55 mm self-calibration on the robotic C-arm: confirmed; "
                  "whether the RPE is at the detector or the isocentre is not in the abstract; DOI not confirmed here",
         ("reprojection_px", "source_mm")),
    _ref("gantry_sag", 0.5, "mm (SD along gravity per plane)", 0.0, 1.0,
         "Daly, Siewerdsen, Cho, Jaffray, Irish. Med Phys 2008", "10.1118/1.2907563",
         "a mobile C-arm flexes by up to 6-8 mm (source and detector X, Y) over its orbit, reproducibly, so that its "
         "calibration removes it; what a calibration made on the CBCT orbit leaves at a fluoroscopic angulation is "
         "not measured: a fraction of a millimetre, swept 0-1 mm",
         "swept", "abstract: departures of 6-8 mm, reproducible and correctable: confirmed", ("sd_mm",)),
    _ref("registration", 0.3, "mm (translation SD per axis; rotation 0.1 deg per 0.3 mm)", 0.2 / _MEAN_3D_PER_SD,
         0.515 / _MEAN_3D_PER_SD,
         "Ruijters, Homan, Mielekamp, van de Haar, Babic. Phys Med Biol 2011", "10.1088/0031-9155/56/16/017",
         "a mean 3D error is 1.596 per-axis SDs: the machine-based 2D-3D registration's < 0.2 mm gives 0.125 mm, the "
         "image-based 3D-3D's 0.515 mm gives 0.32 mm. The paper's CBCT and fluoroscopy share a C-arm (machine-based); "
         "the default sits near the image-based end. Minesinger et al. 2025's 0.12 mm is a fiducial registration error "
         "of another route (a phantom on the robot), not this one",
         "swept", "abstract: 0.515 mm (3D-3D) and < 0.2 mm (machine-based 2D-3D): confirmed",
         ("translation_mm", "rotation_deg")),
    _ref("annotation", 1.0 / math.sqrt(3) / math.sqrt(2), "mm (centroid and radius SD)",
         0.5 / math.sqrt(3) / math.sqrt(2), 1.5 / math.sqrt(3) / math.sqrt(2),
         "derived (docs/error-budget.md); the paper's CBCT voxel size is not stated", "",
         "each extreme point of a hand-drawn sphere within +-1 voxel (uniform) of a 1 mm CBCT: a centroid or radius "
         "has SD (1/sqrt(3))/sqrt(2) mm; voxels of 0.5-1.5 mm give the range. Isotropic: the paper's radius MAE is "
         "smallest along depth (0.3 vs 0.6 mm, Table II), so no figure supports a depth-elongated annotation error",
         "derived", "the paper's Table II radius MAE per direction: confirmed", ("centroid_mm", "radius_mm")),
    _ref("robot", 0.03, "mm (landing noise SD per axis)", 0.015, 0.03,
         "Wagner et al. IEEE Trans Biomed Eng 2023, §II-C (UR5e data sheet)", "10.1109/TBME.2022.3198600",
         "the +-0.03 mm pose repeatability taken as one SD (as two SD: 0.015 mm)",
         "cited", "§II-C: 'a pose repeatability of +-0.03 mm': confirmed", ("sd_mm",)),
    _ref("phantom_motion", 0.2, "mm (SD per axis, per experiment)", 0.0, 0.5, "none found", "",
         "an agarose phantom in a water bath shifting between the treatment and the post-treatment CBCT as the "
         "transducer is lifted out: no measurement, swept 0-0.5 mm", "swept", "no reference", ("sd_mm",)),
    _ref("replacement", 0.39, "mm (SD per transducer axis, per experiment)", 0.0, 0.6,
         "Minesinger, Laeseke, Falk, Hennen, Speidel, Wagner. J Appl Clin Med Phys 2025", "10.1002/acm2.70132",
         "the transducer re-attached before each of 8 treatments (one user, one day): short-axis error SD 0.60 mm; "
         "less this model's annotation (0.41), phantom motion (0.2) and robot (0.03 mm) in quadrature: 0.39 mm per "
         "axis (their registration's share not subtracted: an upper reading). Their second day's SD, 0.18 mm, leaves "
         "nothing: the range runs 0-0.6 mm",
         "derived", "abstract: 'Targeting error significantly increased along the transducer's short axis between days "
                    "(0.88 +- 0.60 vs 1.43 +- 0.18 mm)', the transducer reattached after each registration: confirmed",
         ("sd_mm",)),
    _ref("carm_reproducibility", 0.1, "mm (projection shift SD per detector axis, per acquisition)", 0.06, 0.25,
         "Fahrig, Holdsworth. Med Phys 2000", "10.1118/1.598854",
         "the gantry's motion reproducible within a day to a mean SD of 0.11 mm (tangential) and 0.08 mm (axial), "
         "over 21 months 0.10 and 0.06 mm: read as the projection's shift on the detector. The range's top is Daly et "
         "al. 2008's short-term reproducibility bound of the source and detector positions (< 0.25 mm; piercing point "
         "< 0.16 mm)", "cited",
         "abstracts: Fahrig & Holdsworth 0.11 / 0.08 mm (one day), 0.10 / 0.06 mm (21 months); Daly et al. < 0.16 mm "
         "(piercing point), < 0.25 mm (source-detector X, Y): confirmed", ("shift_mm",)),
    _ref("robot_accuracy", 0.65, "mm (RMS TCP position error, one arm per lab)", 0.2, 1.0,
         "Slamani, Nubiola, Bonev. Industrial Robot 39(1):57-68, 2012", "",
         "an uncalibrated ABB IRB 1600: position repeatability better than 37 um, linear position accuracy better "
         "than 650 um. Drawn as per-lab DH errors (lengths, twists, joint zero offsets) scaled to this RMS error over "
         "the UR5e's working poses (_magnitudes.RMS_TCP_MM_PER_UNIT_DH_ERROR). No UR5e measurement found (Universal "
         "Robots calibrates each arm's kinematics at the factory): swept 0.2-1.0 mm",
         "swept", "the preprint's abstract: 37 um and 650 um: confirmed; DOI not confirmed here",
         ("position_mm",)),
)}


def _reference(name: str) -> SourceReference:
    if name not in SOURCE_REFERENCES:
        raise ValueError(f"source must be one of {LAB_SOURCES}, got {name!r}")
    return SOURCE_REFERENCES[name]


def sweep_values(name: str, n: int = 5) -> np.ndarray:
    """Headline magnitudes of a source evenly over its range: what a band over the source sweeps.

    Args:
        name: the source (a key of :data:`SOURCE_REFERENCES`).
        n: the values (>= 2).

    Returns:
        ``n`` values from low to high, in the reference's ``unit``.

    Raises:
        ValueError: ``n`` not an integer >= 2, or an unknown source.
    """
    ref = _reference(name)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n must be an integer >= 2, got {n!r}")
    return np.linspace(ref.low, ref.high, int(n))


def magnitudes_at(name: str, value: float):
    """Source ``name``'s magnitudes (its dataclass) at headline magnitude ``value`` (the reference's
    unit, >= 0): the default's scaled fields times ``value / default value``."""
    ref = _reference(name)
    value = float(value)
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"value must be finite and >= 0 ({ref.unit}), got {value!r}")
    default, factor = getattr(LabErrorModel(), name), value / ref.value
    scaled = {}
    for f in ref.fields:
        v = getattr(default, f)
        scaled[f] = tuple(factor * x for x in v) if isinstance(v, tuple) else factor * v
    return dataclasses.replace(default, **scaled)


def model_at(name: str, value: float, base: LabErrorModel | None = None) -> LabErrorModel:
    """A lab error model with one source on at another headline magnitude (:func:`magnitudes_at`:
    every scaled field of the default times ``value`` / default).

    Args:
        name: the source (a key of :data:`SOURCE_REFERENCES`).
        value: its headline magnitude, in the reference's ``unit``.
        base: the other sources as this model has them; None: every source at its default.

    Returns:
        The :class:`~histostudy.study.budget.LabErrorModel`.

    Raises:
        TypeError: ``base`` is not a LabErrorModel.
        ValueError: an unknown source, or a magnitude its dataclass refuses.
    """
    base = LabErrorModel() if base is None else base
    if not isinstance(base, LabErrorModel):
        raise TypeError(f"base must be a LabErrorModel, got {type(base).__name__}")
    return dataclasses.replace(base, **{name: magnitudes_at(name, value)})


def references_table() -> pd.DataFrame:
    """One row per source (LAB_SOURCES order): value, unit, low, high, status, reference, doi,
    mapping and what was checked."""
    return pd.DataFrame([{"source": r.source, "value": r.value, "unit": r.unit, "low": r.low, "high": r.high,
                          "status": r.status, "reference": r.reference, "doi": r.doi, "mapping": r.mapping,
                          "checked": r.checked} for r in (SOURCE_REFERENCES[n] for n in LAB_SOURCES)])
