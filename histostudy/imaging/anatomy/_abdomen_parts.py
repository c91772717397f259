"""The parts of the random abdomen of :func:`~histostudy.imaging.anatomy._random.random_abdomen` (§II-B.2): body
outline, fat and soft tissue, organs, gas, spine and ribs, each drawn in a fixed order (same Generator
state, same scene). Body frame: origin at the body centre, long axis along z, mm; attenuations in 1/mm
are differences to whatever else is there (docs/imaging.md, "The scenes")."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from histostudy.geometry import rotation_about_axis

from ._csg import Intersection
from ._params import AbdomenSpec, _Draw
from ._shapes import Box, Ellipsoid, EllipticCylinder, Primitive

__all__: list[str] = []


def _rot_x_rad(rad: float) -> np.ndarray:
    """3x3 rotation by ``rad`` radians about the x axis."""
    return rotation_about_axis([1.0, 0.0, 0.0], rad)


def _rot_y_deg(deg: float) -> np.ndarray:
    """3x3 rotation by ``deg`` degrees about the y axis (the vertical: a yaw of the patient)."""
    return rotation_about_axis([0.0, 1.0, 0.0], np.deg2rad(deg))


def _rot_z_deg(deg: float) -> np.ndarray:
    """3x3 rotation by ``deg`` degrees about the z axis (the body's long axis)."""
    return rotation_about_axis([0.0, 0.0, 1.0], np.deg2rad(deg))


def _rot_z_rad(rad: float) -> np.ndarray:
    """3x3 rotation by ``rad`` radians about the z axis (the body's long axis)."""
    return rotation_about_axis([0.0, 0.0, 1.0], rad)


def _frame_from_axis(axis, up_hint) -> np.ndarray:
    """Rotation whose local z is ``axis`` and local y is as close to ``up_hint`` as possible."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    y = np.asarray(up_hint, float) - z * (z @ up_hint)
    if np.linalg.norm(y) < 1e-9:
        y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


@dataclass(frozen=True, eq=False)
class _Body:
    """The drawn body outline and its placement in the world (CBCT frame, mm, LPS).

    ``A``, ``B``: semi-axes of the elliptic cross-section (x: left-right, y: anterior-posterior);
    ``half_len``: half its length along z; ``back_y``: the flat back face (body frame, +y);
    ``R``, ``t``, ``T``: world <- body rotation, translation and 4x4 transform; ``cy``: the body
    centre's world y; ``depth``: the isocentre's depth below the anterior skin; ``target``: the
    isocentre in body coordinates.
    """

    A: float
    B: float
    half_len: float
    back_y: float
    R: np.ndarray
    t: np.ndarray
    T: np.ndarray
    cy: float
    depth: float
    target: np.ndarray

    def shape(self, inset: float) -> Intersection:
        """The body's outline shrunk by ``inset`` mm: an elliptic cylinder cut by the flat back
        (body frame, no attenuation set)."""
        A, B, half_len, back_y = self.A, self.B, self.half_len, self.back_y
        cyl = EllipticCylinder(np.array([0, 0, 0]), np.array([A - inset, B - inset]), half_len - inset)
        cut = Box(np.array([0.0, (back_y - inset - B - 10.0) / 2.0, 0.0]),
                  np.array([A + 10.0, (back_y - inset + B + 10.0) / 2.0, half_len + 10.0]))
        return Intersection((cyl, cut))


def _place_body(draw: _Draw) -> _Body:
    """Draw the body's size, yaw and shift and place it so that the anterior skin on the vertical
    line through the isocentre lies ``target_depth_mm`` above it (§II-B.2 stand-in; mm, CBCT
    frame). Raises ``ValueError`` when the shift puts the isocentre outside the body."""
    A, B = draw("body_width_mm") / 2.0, draw("body_depth_mm") / 2.0
    half_len = draw("body_length_mm") / 2.0
    flat = draw("back_flattening_mm")
    sx, sz = draw("body_shift_x_mm"), draw("body_shift_z_mm")
    R_body = _rot_y_deg(draw("body_yaw_deg"))
    depth = draw("target_depth_mm")
    # The vertical line through the isocentre stays vertical in the body frame (yaw is about y);
    # place the body so that the skin on that line is `depth` anterior of the isocentre.
    xb = (R_body.T @ np.array([-sx, 0.0, -sz]))[0]
    if abs(xb) >= 0.8 * A:
        raise ValueError(f"body_shift_x_mm {sx:.1f} puts the isocentre outside the body (half width {A:.1f} mm)")
    cy = -depth + B * math.sqrt(1.0 - (xb / A) ** 2)
    t_body = np.array([sx, cy, sz])
    T_body = np.eye(4)
    T_body[:3, :3], T_body[:3, 3] = R_body, t_body
    target_b = R_body.T @ (-t_body)             # the isocentre in body coordinates
    return _Body(A=A, B=B, half_len=half_len, back_y=B - flat, R=R_body, t=t_body, T=T_body, cy=cy, depth=depth,
                 target=target_b)


class _Tissue:
    """The soft tissue inside the body's fat layer (body frame, mm): inner semi-axes ``Ai``,
    ``Bi``, the fat thickness, the soft tissue's ``mu_soft`` [1/mm], the isocentre's ``tz``, and
    the inner outline ``ring`` that organs and gas pockets must keep clear of."""

    def __init__(self, body: _Body, fat: float, mu_soft: float):
        self.Ai, self.Bi = body.A - fat, body.B - fat       # inner (sub-fat) semi-axes
        self.fat, self.mu_soft = fat, mu_soft
        self.back_y, self.half_len = body.back_y, body.half_len
        self.tz = body.target[2]
        theta = np.linspace(0.0, 2.0 * np.pi, 721)
        self.ring = np.stack([self.Ai * np.cos(theta), self.Bi * np.sin(theta)], axis=1)

    def clearance(self, c) -> float:
        """Radius (mm) of the largest ball around ``c`` (body frame) inside the soft tissue, less a
        2 mm margin; negative outside."""
        ring, Ai, Bi = self.ring, self.Ai, self.Bi
        radial = float(np.min(np.hypot(ring[:, 0] - c[0], ring[:, 1] - c[1])))
        inside = (c[0] / Ai) ** 2 + (c[1] / Bi) ** 2 < 1.0
        r = min(radial, self.back_y - self.fat - c[1], self.half_len - self.fat - abs(c[2])) if inside else 0.0
        return r - 2.0

    def organ(self, center, axes, R, mu, name) -> Ellipsoid:
        """An ellipsoidal organ (body frame, mm; ``mu`` [1/mm] over soft tissue), shrunk (to no
        less than 0.3 of its size) where it would reach into the fat."""
        axes = np.asarray(axes, float)
        axes = axes * min(1.0, max(0.3, self.clearance(center) / axes.max()))
        return Ellipsoid(center, axes, R, mu, name)


def _body_layers(draw: _Draw, body: _Body) -> tuple[list[Primitive], _Tissue]:
    """Draw the fat and soft-tissue attenuations [1/mm] and the fat's thickness [mm]: the body as
    fat with soft tissue inside (body frame, §II-B.2 stand-in), and that soft tissue."""
    mu_fat, mu_soft = draw("mu_fat_per_mm"), draw("mu_soft_tissue_per_mm")
    fat = draw("fat_mm")
    layers: list[Primitive] = [
        dataclasses.replace(body.shape(0.0), mu_per_mm=mu_fat, name="body (fat)"),
        dataclasses.replace(body.shape(fat), mu_per_mm=mu_soft - mu_fat, name="body (soft tissue)"),
    ]
    return layers, _Tissue(body, fat, mu_soft)


def _organs(draw: _Draw, tissue: _Tissue) -> tuple[list[Ellipsoid], Ellipsoid, float, float]:
    """Draw the liver, the kidneys (either side of the spine), the spleen and the stomach as
    tilted ellipsoids in the soft tissue (body frame, mm; §II-B.2 stand-in). Returns the organs,
    the stomach, and the spine's ``x`` and ``y`` (drawn between the liver and the kidneys)."""
    Ai, Bi, tz = tissue.Ai, tissue.Bi, tissue.tz

    def tilt():
        return _rot_z_deg(draw("organ_tilt_deg")) @ _rot_y_deg(draw("organ_tilt_deg"))

    def at(frac_name: str, z_name: str) -> np.ndarray:
        fx, fy = draw(frac_name)
        return np.array([fx * Ai, fy * Bi, tz + draw(z_name)])

    organ = tissue.organ
    out = [organ(at("liver_center_frac", "liver_z_offset_mm"), draw("liver_semi_axes_mm"), tilt(),
                 draw("liver_delta_mu"), "liver")]
    spine_y = tissue.back_y - draw("spine_depth_mm")
    spine_x = draw("spine_shift_x_mm")
    kd = draw("kidney_delta_mu")
    for side in (-1.0, 1.0):
        c = np.array([spine_x + side * draw("kidney_lateral_frac") * Ai, spine_y - draw("kidney_anterior_mm"),
                      tz + draw("kidney_z_offset_mm")])
        out.append(organ(c, draw("kidney_semi_axes_mm"), tilt(), kd, "kidney"))
    out.append(organ(at("spleen_center_frac", "spleen_z_offset_mm"), draw("spleen_semi_axes_mm"), tilt(),
                     draw("spleen_delta_mu"), "spleen"))
    stomach = organ(at("stomach_center_frac", "stomach_z_offset_mm"), draw("stomach_semi_axes_mm"), tilt(),
                    draw("stomach_delta_mu"), "stomach")
    out.append(stomach)
    return out, stomach, spine_x, spine_y


def _stomach_gas(draw: _Draw, p: AbdomenSpec, stomach: Ellipsoid,
                 mu_soft: float) -> tuple[Ellipsoid, tuple[np.ndarray, float]] | None:
    """With probability ``stomach_gas_probability``, a gas cap at the anterior (upper, supine)
    side of the stomach (body frame, mm; ``mu`` cancels tissue and stomach) and its bounding ball
    ``(centre, radius)``; else None."""
    if draw.rng.random() < p.stomach_gas_probability:
        u = draw.uniform
        s_min = float(stomach.semi_axes_mm.min())
        r_gas = draw("stomach_gas_radius_frac") * s_min
        # Supine: gas rises to the anterior (-y) side. A ball with |c' - c| + r <= the smallest
        # semi-axis lies inside the stomach.
        c_gas = stomach.center_mm + np.array([0.0, -(s_min - r_gas) * u(0.5, 0.95), 0.0])
        gas = Ellipsoid(c_gas, np.array([r_gas, r_gas * u(0.5, 0.9), r_gas]), mu_per_mm=-(mu_soft + stomach.mu_per_mm),
                        name="stomach gas")
        return gas, (c_gas, r_gas)
    return None


def _vertebra(spine_x: float, spine_y: float, zc: float, a_vb: float, b_vb: float, vb_h: float, mu_vb: float,
              mu_post: float) -> list[Primitive]:
    """One vertebra centred at height ``zc`` (body frame, mm): the body (an elliptic cylinder of
    semi-axes ``a_vb``, ``b_vb``, height ``vb_h``), lamina, spinous process, pedicles and
    transverse processes (``mu_post`` [1/mm]) behind it."""
    y_canal = spine_y + b_vb + 9.0            # centre of the spinal canal
    out: list[Primitive] = [
        EllipticCylinder(np.array([spine_x, spine_y, zc]), np.array([a_vb, b_vb]), vb_h / 2.0, mu_per_mm=mu_vb,
                         name="vertebral body"),
        Box(np.array([spine_x, y_canal + 12.0, zc]), np.array([12.0, 3.5, vb_h * 0.38]), mu_per_mm=mu_post,
            name="lamina"),
        Box(np.array([spine_x, y_canal + 28.0, zc - 4.0]), np.array([3.0, 14.0, vb_h * 0.25]), _rot_x_rad(-0.35),
            mu_per_mm=mu_post, name="spinous process"),
    ]
    for side in (-1.0, 1.0):
        out += [
            Ellipsoid(np.array([spine_x + side * 11.0, y_canal, zc]), np.array([4.0, 8.5, 6.5]), mu_per_mm=mu_post,
                      name="pedicle"),
            Ellipsoid(np.array([spine_x + side * 30.0, y_canal + 4.0, zc]), np.array([14.0, 4.0, 5.0]),
                      _rot_z_rad(side * 0.25), mu_per_mm=mu_post, name="transverse process"),
        ]
    return out


def _vertebral_column(draw: _Draw, tissue: _Tissue, spine_x: float, spine_y: float) -> tuple[list[Primitive], float]:
    """Draw the vertebrae's size and attenuation and stack them along z around the isocentre's
    height (body frame, mm; §II-B.2 stand-in). Returns the primitives and the vertebral bodies'
    antero-posterior semi-axis ``b_vb`` (mm), where the ribs' necks attach."""
    vb_w = draw("vertebral_body_width_mm")
    vb_h = draw("vertebral_body_height_mm")
    disc = draw("disc_mm")
    mu_vb, mu_post = draw("vertebra_delta_mu"), draw("posterior_elements_delta_mu")
    extent = draw("spine_half_extent_mm")
    pitch = vb_h + disc
    tz, half_len = tissue.tz, tissue.half_len
    z_lo, z_hi = max(tz - extent, -half_len + 20), min(tz + extent, half_len - 20)
    phase = draw.uniform(0.0, pitch)
    a_vb, b_vb = vb_w / 2.0, vb_w * draw("vertebral_body_depth_frac")
    out: list[Primitive] = []
    for zc in np.arange(z_lo + phase, z_hi, pitch):
        out += _vertebra(spine_x, spine_y, zc, a_vb, b_vb, vb_h, mu_vb, mu_post)
    return out, b_vb


def _rib(neck: np.ndarray, side: float, start_x: float, span: float, z0: float, Ar: float, Br: float, drop: float,
         rib_t: float, rib_h: float, mu_rib: float) -> list[EllipticCylinder]:
    """One rib on ``side`` (-1: patient's right, +1: left) as short elliptic cylinders (body
    frame, mm): from the ``neck`` point at the transverse process round the elliptic arc of
    semi-axes ``Ar``, ``Br`` over ``span`` rad, dropping by ``drop`` mm towards the front."""
    phi0 = math.acos(min(0.99, start_x / Ar))       # posterior end at |x| = start_x, y > 0
    # From the back round the side (|x| = Ar at phi = pi) towards the front (y < 0).
    phis = math.pi - phi0 + np.linspace(0.0, span, max(4, int(span * (Ar + Br) / 2 / 40.0) + 1))
    pts = np.stack([-side * Ar * np.cos(phis), Br * np.sin(phis), z0 - drop * (phis - phis[0]) / span], axis=1)
    pts = np.vstack([neck, pts])
    out = []
    for a, b in zip(pts[:-1], pts[1:]):
        seg = b - a
        length = float(np.linalg.norm(seg))
        R = _frame_from_axis(seg, [0.0, 0.0, 1.0])
        # Cross-section: thickness along the radial direction (local x), height ~ z (local y).
        out.append(EllipticCylinder((a + b) / 2.0, np.array([rib_t / 2.0, rib_h / 2.0]), length / 2.0 + 0.3, R, mu_rib,
                                    "rib"))
    return out


def _ribs(draw: _Draw, tissue: _Tissue, body: _Body, spine_x: float, spine_y: float,
          b_vb: float) -> list[EllipticCylinder]:
    """Draw the rib pairs' number, height, spacing, size and reach, and build them as arcs just
    inside the fat (body frame, mm; §II-B.2 stand-in): the lowest (floating) ribs short, the ones
    above reaching round to the front."""
    n_ribs = draw.integer("rib_pairs")
    z_rib = draw("rib_lowest_z_mm") - body.t[2]      # body frame (yaw ignored: a few degrees)
    spacing = draw("rib_spacing_mm")
    rib_t, rib_h = draw("rib_thickness_mm"), draw("rib_height_mm")
    drop, mu_rib = draw("rib_drop_mm"), draw("rib_delta_mu")
    inset = draw("rib_inset_mm")
    span_lowest, span_max = draw("rib_span_lowest_deg"), draw("rib_span_max_deg")
    Ar, Br = tissue.Ai - inset, tissue.Bi - inset
    half_len = body.half_len
    out: list[EllipticCylinder] = []
    for k in range(n_ribs):
        z0 = z_rib + k * spacing
        if not (-half_len + 30 < z0 < half_len - 30):
            continue
        span = np.deg2rad(min(span_lowest + 28.0 * k, span_max))
        for side in (-1.0, 1.0):                          # -1: patient's right (x < 0), +1: left
            start_x = draw("rib_start_x_mm")
            # A short neck from the transverse process to the posterior angle of the rib.
            neck = np.array([[spine_x + side * 46.0, spine_y + b_vb + 12.0, z0 + 4.0]])
            out += _rib(neck, side, start_x, span, z0, Ar, Br, drop, rib_t, rib_h, mu_rib)
    return out


def _bowel_gas(draw: _Draw, p: AbdomenSpec, tissue: _Tissue, gas_balls: list, avoid: list) -> list[Ellipsoid]:
    """Draw ``gas_pockets`` bowel-gas ellipsoids in the soft tissue (body frame, mm; ``mu``
    cancels the soft tissue), each placed in up to 50 tries clear of the fat and, by 1 mm, of the
    bounding balls in ``gas_balls`` and ``avoid``; ``gas_balls`` grows by each pocket placed."""
    u = draw.uniform
    n_gas = draw.integer("gas_pockets")
    lo_r, hi_r = p.gas_semi_axis_mm
    gz = p.gas_z_extent_mm[1]
    out: list[Ellipsoid] = []
    for _ in range(n_gas):
        for _attempt in range(50):
            axes = u(lo_r, hi_r, size=3)
            r = float(axes.max())
            fx, fy = draw("gas_region_frac")
            c = np.array([fx * tissue.Ai, fy * tissue.Bi, tissue.tz + u(-gz, gz)])
            R_gas = _rot_z_rad(u(0, np.pi)) @ _rot_y_deg(u(-90, 90))
            if tissue.clearance(c) >= r and all(np.linalg.norm(c - c2) >= r + r2 + 1.0
                                                for c2, r2 in gas_balls + avoid):
                out.append(Ellipsoid(c, axes, R_gas, -tissue.mu_soft, "bowel gas"))
                gas_balls.append((c, r))
                break
    return out
