"""The ranges the random abdomen (§II-B.2) and phantom set-up (§II-D) scenes draw from, one uniform range
per named quantity (lengths in mm, attenuations in 1/mm, angles in deg), and the recorded draws."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from histostudy.core import is_real

__all__ = [
    "AbdomenSpec",
    "PhantomSceneSpec",
]


def _range(name: str, value, integer: bool = False) -> tuple[float, float]:
    """``value`` as a ``(low, high)`` range of finite floats; a bare number ``v`` is ``(v, v)``."""
    if is_real(value):
        value = (value, value)
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (low, high) range or a number, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"{name} must be a finite range with low <= high, got {value!r}")
    if integer and (lo != int(lo) or hi != int(hi) or lo < 0):
        raise ValueError(f"{name} must be a range of non-negative integers, got {value!r}")
    return (lo, hi)


def _normalise_params(params) -> None:
    """Validate a params dataclass in place: every field a range, a tuple of ranges (one per
    component, as in its default) or, for ``*_probability`` fields, a probability."""
    int_fields: frozenset[str] = getattr(params, "_INT_FIELDS", frozenset())
    for f in dataclasses.fields(params):
        value = getattr(params, f.name)
        norm: float | tuple[float, float] | tuple[tuple[float, float], ...]
        if f.name.endswith("_probability"):
            if not (is_real(value) and 0.0 <= float(value) <= 1.0):
                raise ValueError(f"{f.name} must be a probability in [0, 1], got {value!r}")
            norm = float(value)
        elif isinstance(f.default, tuple) and f.default and isinstance(f.default[0], tuple):
            # One range per component, e.g. three semi-axes; a flat sequence fixes each component.
            k = len(f.default)
            if not isinstance(value, (tuple, list)) or len(value) != k:
                raise ValueError(f"{f.name} must be {k} ranges (low, high), one per component, got {value!r}")
            norm = tuple(_range(f"{f.name}[{i}]", v) for i, v in enumerate(value))
        else:
            norm = _range(f.name, value, integer=f.name in int_fields)
        object.__setattr__(params, f.name, norm)


def _with_overrides(cls, params, overrides: dict):
    if params is None:
        params = cls()
    elif not isinstance(params, cls):
        raise TypeError(f"params must be a {cls.__name__} or None, got {type(params).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} field(s) {unknown}; expected some of {sorted(names)}")
    return dataclasses.replace(params, **overrides)


class _Draw:
    """Uniform draws from the named ranges of a params dataclass, recording what was drawn."""

    def __init__(self, rng: np.random.Generator, params):
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.rng, self.params = rng, params
        self.drawn: dict[str, float | int | list[float]] = {}

    def __call__(self, name: str):
        """A float from a range field, an array (one value per component) from a tuple of ranges."""
        value = getattr(self.params, name)
        if isinstance(value[0], tuple):
            components = np.array([self.rng.uniform(lo, hi) for lo, hi in value])
            self.drawn[name] = components.tolist()
            return components
        out = float(self.rng.uniform(*value))
        self.drawn[name] = out
        return out

    def integer(self, name: str) -> int:
        lo, hi = getattr(self.params, name)
        value = int(self.rng.integers(int(lo), int(hi) + 1))
        self.drawn[name] = value
        return value

    def uniform(self, lo, hi, size=None):
        return self.rng.uniform(lo, hi, size=size)


@dataclass(frozen=True)
class AbdomenSpec:
    """Ranges ``(low, high)`` the random abdomen draws from (uniform); lengths mm, mu in 1/mm.

    Effective attenuation at ~70 keV: water/soft tissue 0.019-0.021 /mm, fat ~0.017, cortical
    bone ~0.045-0.05, air ~0. Organ, bone and gas values are *differences* to soft tissue. The
    body outline is porcine/human-abdomen sized; positions of organs are fractions of the
    body's inner (sub-fat) semi-axes so they scale with the body.
    """

    # body outline and placement
    body_width_mm: tuple = (300.0, 380.0)          # left-right
    body_depth_mm: tuple = (200.0, 260.0)          # anterior-posterior
    body_length_mm: tuple = (700.0, 900.0)         # along z
    back_flattening_mm: tuple = (5.0, 25.0)        # flat contact face on the table
    body_shift_x_mm: tuple = (-30.0, 30.0)         # body axis left-right of the isocentre
    body_shift_z_mm: tuple = (-60.0, 60.0)         # body centre head-feet of the isocentre
    body_yaw_deg: tuple = (-4.0, 4.0)              # body axis not quite parallel to the table axis
    target_depth_mm: tuple = (50.0, 110.0)         # isocentre (focal point) below the anterior skin
    fat_mm: tuple = (8.0, 30.0)                    # subcutaneous fat layer
    mu_fat_per_mm: tuple = (0.0165, 0.0175)
    mu_soft_tissue_per_mm: tuple = (0.0195, 0.0210)
    # organs: ellipsoids in the body frame. *_center_frac: centre (x, y) as fractions of the inner
    # semi-axes (+x left, +y posterior); *_z_offset_mm: centre z above the isocentre. Organs
    # reaching into the fat are shrunk to fit. mu: differences to soft tissue.
    organ_tilt_deg: tuple = (-20.0, 20.0)          # each organ's rotation about z (and y)
    liver_center_frac: tuple = ((-0.42, -0.30), (-0.15, 0.0))
    liver_z_offset_mm: tuple = (-20.0, 100.0)
    liver_semi_axes_mm: tuple = ((55.0, 75.0), (50.0, 65.0), (80.0, 105.0))
    liver_delta_mu: tuple = (0.0005, 0.0015)
    kidney_lateral_frac: tuple = (0.30, 0.40)      # |x| from the spine, fraction of the inner half width
    kidney_anterior_mm: tuple = (0.0, 15.0)        # centre anterior of the vertebral bodies
    kidney_z_offset_mm: tuple = (-30.0, 60.0)
    kidney_semi_axes_mm: tuple = ((25.0, 32.0), (20.0, 27.0), (45.0, 60.0))
    kidney_delta_mu: tuple = (0.0005, 0.0012)
    spleen_center_frac: tuple = ((0.40, 0.55), (0.05, 0.30))
    spleen_z_offset_mm: tuple = (30.0, 110.0)
    spleen_semi_axes_mm: tuple = ((20.0, 30.0), (40.0, 55.0), (50.0, 70.0))
    spleen_delta_mu: tuple = (0.0005, 0.0012)
    stomach_center_frac: tuple = ((0.15, 0.35), (-0.35, -0.15))
    stomach_z_offset_mm: tuple = (40.0, 120.0)
    stomach_semi_axes_mm: tuple = ((50.0, 70.0), (35.0, 50.0), (45.0, 65.0))
    stomach_delta_mu: tuple = (-0.0008, 0.0)       # mostly fluid content
    stomach_gas_probability: float = 0.7
    stomach_gas_radius_frac: tuple = (0.25, 0.5)   # of the stomach's smallest semi-axis
    # spine (vertebral bodies + posterior elements)
    spine_depth_mm: tuple = (60.0, 85.0)           # back skin to vertebral body centre
    spine_shift_x_mm: tuple = (-8.0, 8.0)
    spine_half_extent_mm: tuple = (250.0, 250.0)   # spine modelled within this z of the isocentre
    vertebral_body_width_mm: tuple = (40.0, 52.0)
    vertebral_body_depth_frac: tuple = (0.34, 0.40)  # AP semi-axis per width (a kidney-shaped oval)
    vertebral_body_height_mm: tuple = (22.0, 30.0)
    disc_mm: tuple = (5.0, 9.0)
    vertebra_delta_mu: tuple = (0.010, 0.016)      # trabecular body with its thin cortex
    posterior_elements_delta_mu: tuple = (0.016, 0.024)
    # ribs (pairs counted from the lowest one up)
    rib_pairs: tuple = (5, 8)
    rib_lowest_z_mm: tuple = (-20.0, 90.0)         # posterior end of the lowest rib, world z
    rib_spacing_mm: tuple = (26.0, 36.0)
    rib_thickness_mm: tuple = (6.0, 9.0)
    rib_height_mm: tuple = (10.0, 14.0)
    rib_drop_mm: tuple = (25.0, 55.0)              # how far a rib descends from back to front
    rib_delta_mu: tuple = (0.012, 0.020)
    rib_inset_mm: tuple = (4.0, 12.0)              # ribs this far inside the fat
    rib_span_lowest_deg: tuple = (85.0, 105.0)     # arc of the lowest (floating) rib; +28 deg per rib up
    rib_span_max_deg: tuple = (190.0, 210.0)       # ...up to this (ribs reaching round to the front)
    rib_start_x_mm: tuple = (40.0, 55.0)           # |x| of a rib's posterior angle
    # bowel gas (mu = -soft tissue: air replaces tissue)
    gas_pockets: tuple = (3, 9)
    gas_semi_axis_mm: tuple = (6.0, 25.0)
    gas_region_frac: tuple = ((-0.7, 0.7), (-0.8, 0.2))   # centres (x, y), fractions of inner semi-axes
    gas_z_extent_mm: tuple = (150.0, 150.0)        # pockets within this z of the isocentre
    # carbon-fibre table under the back
    table_width_mm: tuple = (450.0, 520.0)
    table_thickness_mm: tuple = (35.0, 55.0)
    table_shift_x_mm: tuple = (-20.0, 20.0)
    table_mu_per_mm: tuple = (0.0025, 0.0040)      # sandwich of carbon skins and foam, averaged
    # water bath on the anterior surface
    bath_probability: float = 1.0                  # 0: no bath (a bare animal projection)
    bath_width_mm: tuple = (220.0, 300.0)
    bath_length_mm: tuple = (200.0, 300.0)
    bath_height_mm: tuple = (100.0, 160.0)         # water column above the skin apex
    bath_sink_mm: tuple = (15.0, 40.0)             # membrane pressed into the soft abdomen
    bath_shift_mm: tuple = (-30.0, 30.0)           # bath centre off the isocentre in x and z
    bath_wall_mm: tuple = (3.0, 6.0)
    mu_water_per_mm: tuple = (0.0192, 0.0198)
    mu_plastic_per_mm: tuple = (0.021, 0.024)      # PMMA/polycarbonate tank walls

    _INT_FIELDS = frozenset({"rib_pairs", "gas_pockets"})

    def __post_init__(self):
        _normalise_params(self)


@dataclass(frozen=True)
class PhantomSceneSpec:
    """Ranges for the phantom studies' scene (§II-D, Fig. 4): a 5x5x5 cm agarose phantom on a
    plastic stand in a degassed water tank on the table. Lengths mm, mu in 1/mm."""

    phantom_edge_mm: tuple = (50.0, 50.0)
    phantom_offset_mm: tuple = ((-10.0, 10.0),) * 3   # phantom centre off the isocentre (x, y, z)
    phantom_yaw_deg: tuple = (-30.0, 30.0)         # rotation about the vertical axis
    agarose_delta_mu: tuple = (0.0002, 0.0010)     # agarose gel + red cells vs. water
    layered_probability: float = 1.0               # the layered barium phantom of §II-D.1
    layer_mm: tuple = (3.5, 4.5)
    barium_delta_mu: tuple = (0.004, 0.008)        # ~2.5 % w/v BaSO4
    stand_height_mm: tuple = (20.0, 60.0)
    stand_half_width_mm: tuple = (20.0, 30.0)
    tank_inner_width_mm: tuple = (280.0, 380.0)    # x
    tank_inner_length_mm: tuple = (220.0, 320.0)   # z
    tank_inner_height_mm: tuple = (220.0, 300.0)   # y
    tank_wall_mm: tuple = (4.0, 8.0)
    tank_shift_mm: tuple = (-40.0, 40.0)           # tank centre off the phantom, in x and z
    water_fill: tuple = (0.75, 0.92)               # water level as a fraction of the tank height
    mu_water_per_mm: tuple = (0.0192, 0.0198)
    mu_plastic_per_mm: tuple = (0.021, 0.024)
    table_width_mm: tuple = (450.0, 520.0)
    table_thickness_mm: tuple = (35.0, 55.0)
    table_mu_per_mm: tuple = (0.0025, 0.0040)

    def __post_init__(self):
        _normalise_params(self)

# the 0.1.0 name, deprecated (CHANGELOG.md)
