"""Random synthetic patient and phantom scenes, the backgrounds of the hybrid fluoroscopy images.

Stands in for the real projections the paper superimposed the transducer on (§II-B.2: "hybrid
images ... real x-ray projections from 12 porcine studies", converted to line integrals of the
linear attenuation coefficient) and for the phantom set-up of §II-D (Fig. 4A: an agarose
phantom in a degassed water bath on the patient table). Instead of recorded projections we
project a random analytic 3-D scene exactly, so that both biplane views see one consistent body.

A random scene is an :class:`~histostudy.imaging.anatomy._scene.Anatomy`: a list of the analytic
solids of :mod:`.anatomy_shapes` and :mod:`.anatomy_csg`, each with a linear attenuation
``mu_per_mm`` [1/mm] that is the *difference* to whatever else is there (bowel gas inside soft
tissue is about -0.02 /mm, bone inside soft tissue about +0.02..0.03 /mm), so that a line
integral is the dimensionless ``sum(mu * chord length in mm)``. The ranges the scenes draw from
are in :mod:`.anatomy_params`. Same Generator state, same scene: the draws' order is part of the
result.

World frame: the CBCT frame, millimetres, origin at the isocentre, DICOM LPS axes (+x patient
left, +y posterior, +z head). The patient lies supine, the table under the back (+y side); the
transducer's water bath sits on the anterior surface (-y side), its focal point near the
isocentre.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from histostudy.geometry import rotation_about_axis
from ._csg import Difference, Intersection
from ._params import AbdomenParams, PhantomParams, _Draw, _with_overrides
from ._scene import Anatomy
from ._shapes import Box, Ellipsoid, EllipticCylinder, Primitive

__all__ = [
    "MIXED_ABDOMEN_PROBABILITY",
    "random_abdomen",
    "random_background",
    "random_phantom_setup",
]

#: Probability of an animal (abdomen) background in ``kind="mixed"``: the paper's segmentation
#: evaluation had 156 animal and 56 phantom images (§III-A).
MIXED_ABDOMEN_PROBABILITY = 156.0 / (156.0 + 56.0)


def _rot_x_rad(rad: float) -> np.ndarray:
    return rotation_about_axis([1.0, 0.0, 0.0], rad)


def _rot_y_deg(deg: float) -> np.ndarray:
    return rotation_about_axis([0.0, 1.0, 0.0], np.deg2rad(deg))


def _rot_z_deg(deg: float) -> np.ndarray:
    return rotation_about_axis([0.0, 0.0, 1.0], np.deg2rad(deg))


def _rot_z_rad(rad: float) -> np.ndarray:
    return rotation_about_axis([0.0, 0.0, 1.0], rad)


def _frame_from_axis(axis, up_hint) -> np.ndarray:
    """Rotation whose local z is ``axis`` and local y is as close to ``up_hint`` as possible."""
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    y = np.asarray(up_hint, float) - z * (z @ up_hint)
    if np.linalg.norm(y) < 1e-9:
        y = np.cross(z, [1.0, 0.0, 0.0])
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def _table(draw: _Draw, table_top_y: float, center_x: float) -> Box:
    thick = draw("table_thickness_mm")
    return Box([center_x, table_top_y + thick / 2.0, 0.0], [draw("table_width_mm") / 2.0, thick / 2.0, 1000.0],
               mu_per_mm=draw("table_mu_per_mm"), name="table")


def random_abdomen(rng: np.random.Generator, params: AbdomenParams | None = None, **overrides) -> Anatomy:
    """A random porcine/human-like abdomen on the table with a water bath on its anterior side.

    Stands in for the 12 porcine studies whose projections the paper's hybrid training images
    were built on (§II-B.2) and for the animal images of the evaluation (§III). The scene: an
    elliptic body (flattened on the table) of fat around soft tissue, liver, kidneys, spleen,
    stomach (with a gas cap when drawn), a vertebral column (bodies, pedicles, lamina, spinous
    and transverse processes) along z, rib pairs as arcs around the body wall, bowel-gas pockets,
    a carbon-fibre table slab and a plastic water bath (water filling down to the skin). The
    isocentre lies ``target_depth_mm`` below the anterior skin. World frame: CBCT, mm, LPS.

    Args:
        rng: the Generator every random draw comes from (same seed -> identical scene).
        params: the ranges to draw from; default :class:`AbdomenParams`.
        **overrides: fields of :class:`AbdomenParams` to replace, a range ``(lo, hi)`` or a number.
    """
    p = _with_overrides(AbdomenParams, params, overrides)
    draw = _Draw(rng, p)
    prims: list[Primitive] = []

    # --- body frame: origin at the body centre, axis along z; world = R_body @ x + t_body -------
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
    back_y = B - flat                           # flat back face, body frame

    def body_shape(inset: float) -> Intersection:
        cyl = EllipticCylinder([0, 0, 0], [A - inset, B - inset], half_len - inset)
        cut = Box([0.0, (back_y - inset - B - 10.0) / 2.0, 0.0],
                  [A + 10.0, (back_y - inset + B + 10.0) / 2.0, half_len + 10.0])
        return Intersection((cyl, cut))

    mu_fat, mu_soft = draw("mu_fat_per_mm"), draw("mu_soft_tissue_per_mm")
    fat = draw("fat_mm")
    Ai, Bi = A - fat, B - fat                  # inner (sub-fat) semi-axes
    local: list[Primitive] = [
        dataclasses.replace(body_shape(0.0), mu_per_mm=mu_fat, name="body (fat)"),
        dataclasses.replace(body_shape(fat), mu_per_mm=mu_soft - mu_fat, name="body (soft tissue)"),
    ]
    tz = target_b[2]

    # --- organs --------------------------------------------------------------------------------
    u = draw.uniform
    theta = np.linspace(0.0, 2.0 * np.pi, 721)
    ring = np.stack([Ai * np.cos(theta), Bi * np.sin(theta)], axis=1)   # inner outline, body frame

    def clearance(c) -> float:
        """Radius of the largest ball around ``c`` inside the soft tissue (2 mm margin)."""
        radial = float(np.min(np.hypot(ring[:, 0] - c[0], ring[:, 1] - c[1])))
        inside = (c[0] / Ai) ** 2 + (c[1] / Bi) ** 2 < 1.0
        r = min(radial, back_y - fat - c[1], half_len - fat - abs(c[2])) if inside else 0.0
        return r - 2.0

    def organ(center, axes, R, mu, name) -> Ellipsoid:
        # Shrink an organ that would reach into the fat, so organs stay inside the soft tissue.
        axes = np.asarray(axes, float)
        axes = axes * min(1.0, max(0.3, clearance(center) / axes.max()))
        return Ellipsoid(center, axes, R, mu, name)

    def tilt():
        return _rot_z_deg(draw("organ_tilt_deg")) @ _rot_y_deg(draw("organ_tilt_deg"))

    def at(frac_name: str, z_name: str) -> np.ndarray:
        fx, fy = draw(frac_name)
        return np.array([fx * Ai, fy * Bi, tz + draw(z_name)])

    local.append(organ(at("liver_center_frac", "liver_z_offset_mm"), draw("liver_semi_axes_mm"), tilt(),
                       draw("liver_delta_mu"), "liver"))
    spine_y = back_y - draw("spine_depth_mm")
    spine_x = draw("spine_shift_x_mm")
    kd = draw("kidney_delta_mu")
    for side in (-1.0, 1.0):
        c = np.array([spine_x + side * draw("kidney_lateral_frac") * Ai, spine_y - draw("kidney_anterior_mm"),
                      tz + draw("kidney_z_offset_mm")])
        local.append(organ(c, draw("kidney_semi_axes_mm"), tilt(), kd, "kidney"))
    local.append(organ(at("spleen_center_frac", "spleen_z_offset_mm"), draw("spleen_semi_axes_mm"), tilt(),
                       draw("spleen_delta_mu"), "spleen"))
    stomach = organ(at("stomach_center_frac", "stomach_z_offset_mm"), draw("stomach_semi_axes_mm"), tilt(),
                    draw("stomach_delta_mu"), "stomach")
    local.append(stomach)
    # Bounding balls of the negative primitives and of what they must not overlap: gas may only
    # replace tissue that is there, so that no line integral (or attenuation) becomes negative.
    gas_balls: list[tuple[np.ndarray, float]] = []
    avoid: list[tuple[np.ndarray, float]] = [(stomach.center_mm, float(stomach.semi_axes_mm.max()))]
    if rng.random() < p.stomach_gas_probability:
        s_min = float(stomach.semi_axes_mm.min())
        r_gas = draw("stomach_gas_radius_frac") * s_min
        # Supine: gas rises to the anterior (-y) side. A ball with |c' - c| + r <= the smallest
        # semi-axis lies inside the stomach.
        c_gas = stomach.center_mm + np.array([0.0, -(s_min - r_gas) * u(0.5, 0.95), 0.0])
        local.append(Ellipsoid(c_gas, [r_gas, r_gas * u(0.5, 0.9), r_gas],
                               mu_per_mm=-(mu_soft + stomach.mu_per_mm), name="stomach gas"))
        gas_balls.append((c_gas, r_gas))

    # --- vertebral column --------------------------------------------------------------------
    vb_w = draw("vertebral_body_width_mm")
    vb_h = draw("vertebral_body_height_mm")
    disc = draw("disc_mm")
    mu_vb, mu_post = draw("vertebra_delta_mu"), draw("posterior_elements_delta_mu")
    extent = draw("spine_half_extent_mm")
    pitch = vb_h + disc
    z_lo, z_hi = max(tz - extent, -half_len + 20), min(tz + extent, half_len - 20)
    phase = u(0.0, pitch)
    a_vb, b_vb = vb_w / 2.0, vb_w * draw("vertebral_body_depth_frac")
    for zc in np.arange(z_lo + phase, z_hi, pitch):
        y_canal = spine_y + b_vb + 9.0            # centre of the spinal canal
        local += [
            EllipticCylinder([spine_x, spine_y, zc], [a_vb, b_vb], vb_h / 2.0, mu_per_mm=mu_vb, name="vertebral body"),
            Box([spine_x, y_canal + 12.0, zc], [12.0, 3.5, vb_h * 0.38], mu_per_mm=mu_post, name="lamina"),
            Box([spine_x, y_canal + 28.0, zc - 4.0], [3.0, 14.0, vb_h * 0.25], _rot_x_rad(-0.35),
                mu_per_mm=mu_post, name="spinous process"),
        ]
        for side in (-1.0, 1.0):
            local += [
                Ellipsoid([spine_x + side * 11.0, y_canal, zc], [4.0, 8.5, 6.5], mu_per_mm=mu_post, name="pedicle"),
                Ellipsoid([spine_x + side * 30.0, y_canal + 4.0, zc], [14.0, 4.0, 5.0], _rot_z_rad(side * 0.25),
                          mu_per_mm=mu_post, name="transverse process"),
            ]

    # --- ribs: arcs of short elliptic cylinders just inside the fat -------------------------------
    n_ribs = draw.integer("rib_pairs")
    z_rib = draw("rib_lowest_z_mm") - t_body[2]      # body frame (yaw ignored: a few degrees)
    spacing = draw("rib_spacing_mm")
    rib_t, rib_h = draw("rib_thickness_mm"), draw("rib_height_mm")
    drop, mu_rib = draw("rib_drop_mm"), draw("rib_delta_mu")
    inset = draw("rib_inset_mm")
    span_lowest, span_max = draw("rib_span_lowest_deg"), draw("rib_span_max_deg")
    Ar, Br = Ai - inset, Bi - inset
    for k in range(n_ribs):
        z0 = z_rib + k * spacing
        if not (-half_len + 30 < z0 < half_len - 30):
            continue
        # Lowest (floating) ribs are short; the ones above reach round to the front.
        span = np.deg2rad(min(span_lowest + 28.0 * k, span_max))
        for side in (-1.0, 1.0):                          # -1: patient's right (x < 0), +1: left
            start_x = draw("rib_start_x_mm")
            phi0 = math.acos(min(0.99, start_x / Ar))       # posterior end at |x| = start_x, y > 0
            # From the back round the side (|x| = Ar at phi = pi) towards the front (y < 0).
            phis = math.pi - phi0 + np.linspace(0.0, span, max(4, int(span * (Ar + Br) / 2 / 40.0) + 1))
            pts = np.stack([-side * Ar * np.cos(phis), Br * np.sin(phis), z0 - drop * (phis - phis[0]) / span], axis=1)
            # A short neck from the transverse process to the posterior angle of the rib.
            neck = np.array([[spine_x + side * 46.0, spine_y + b_vb + 12.0, z0 + 4.0]])
            pts = np.vstack([neck, pts])
            for a, b in zip(pts[:-1], pts[1:]):
                seg = b - a
                length = float(np.linalg.norm(seg))
                R = _frame_from_axis(seg, [0.0, 0.0, 1.0])
                # Cross-section: thickness along the radial direction (local x), height ~ z (local y).
                local.append(EllipticCylinder((a + b) / 2.0, [rib_t / 2.0, rib_h / 2.0], length / 2.0 + 0.3, R,
                                              mu_rib, "rib"))

    # --- bowel gas ------------------------------------------------------------------------------
    n_gas = draw.integer("gas_pockets")
    lo_r, hi_r = p.gas_semi_axis_mm
    gz = p.gas_z_extent_mm[1]
    for _ in range(n_gas):
        for _attempt in range(50):
            axes = u(lo_r, hi_r, size=3)
            r = float(axes.max())
            fx, fy = draw("gas_region_frac")
            c = np.array([fx * Ai, fy * Bi, tz + u(-gz, gz)])
            R_gas = _rot_z_rad(u(0, np.pi)) @ _rot_y_deg(u(-90, 90))
            if clearance(c) >= r and all(np.linalg.norm(c - c2) >= r + r2 + 1.0 for c2, r2 in gas_balls + avoid):
                local.append(Ellipsoid(c, axes, R_gas, -mu_soft, "bowel gas"))
                gas_balls.append((c, r))
                break

    prims += [q.transformed(T_body) for q in local]
    body_outer = prims[0]

    # --- table and water bath (world frame, horizontal) -----------------------------------------------
    table_top = cy + back_y
    prims.append(_table(draw, table_top, sx + draw("table_shift_x_mm")))
    skin_y = -depth
    meta = {}
    if rng.random() < p.bath_probability:
        prims += _water_bath(draw, body_outer, skin_y, meta)
    meta.update(draw.drawn)
    meta.update(anterior_skin_y_mm=skin_y, table_top_y_mm=table_top, body_center_mm=t_body.tolist(),
                body_yaw_rad=float(np.deg2rad(draw.drawn["body_yaw_deg"])), n_primitives=len(prims))
    return Anatomy(tuple(prims), name="random abdomen", kind="abdomen", meta=meta)


def _water_bath(draw: _Draw, body_outer: Primitive, skin_y: float, meta: dict) -> list[Primitive]:
    """A plastic water bath on the anterior skin: its water fills the box down to the membrane,
    minus the body (so it follows the curved abdomen); its four walls stop at the skin too."""
    bw, bl, bh = draw("bath_width_mm") / 2.0, draw("bath_length_mm") / 2.0, draw("bath_height_mm")
    sink, wall = draw("bath_sink_mm"), draw("bath_wall_mm")
    bx, bz = draw("bath_shift_mm"), draw("bath_shift_mm")
    mu_w, mu_pl = draw("mu_water_per_mm"), draw("mu_plastic_per_mm")
    y_bottom, y_top = skin_y + sink, skin_y - bh
    water = Box([bx, (y_bottom + y_top) / 2.0, bz], [bw, (y_bottom - y_top) / 2.0, bl])
    out: list[Primitive] = [Difference(water, body_outer, mu_per_mm=mu_w, name="water bath")]
    wall_top = y_top - 20.0                     # the walls stand a little above the water
    wall_half_y, wall_cy = (y_bottom - wall_top) / 2.0, (y_bottom + wall_top) / 2.0
    for sgn in (-1.0, 1.0):
        walls = [Box([bx + sgn * (bw + wall / 2.0), wall_cy, bz], [wall / 2.0, wall_half_y, bl + wall]),
                 Box([bx, wall_cy, bz + sgn * (bl + wall / 2.0)], [bw, wall_half_y, wall / 2.0])]
        out += [Difference(w, body_outer, mu_per_mm=mu_pl, name="bath wall") for w in walls]
    meta.update(bath_top_y_mm=y_top, bath_bottom_y_mm=y_bottom, bath_center_mm=[bx, (y_bottom + y_top) / 2.0, bz],
                bath_half_sizes_mm=[bw, (y_bottom - y_top) / 2.0, bl])
    return out


def random_phantom_setup(rng: np.random.Generator, params: PhantomParams | None = None, **overrides) -> Anatomy:
    """The phantom studies' scene (§II-D, Fig. 4A): an agarose phantom in a water tank on the table.

    A ``phantom_edge_mm`` (5 cm) agarose cube, layered with barium when drawn (§II-D.1,
    ~4 mm layers stacked vertically as poured), stands on a plastic block in a degassed water
    tank (plastic walls, open top) on the carbon-fibre table. The phantom centre lies within
    ``phantom_offset_mm`` of the isocentre, where the transducer's focal point is aimed.
    World frame: CBCT, mm, LPS.

    Args:
        rng: the Generator every random draw comes from.
        params: the ranges to draw from; default :class:`PhantomParams`.
        **overrides: fields of :class:`PhantomParams` to replace, a range or a number.
    """
    p = _with_overrides(PhantomParams, params, overrides)
    draw = _Draw(rng, p)
    edge = draw("phantom_edge_mm")
    pc = draw("phantom_offset_mm")
    R_ph = _rot_y_deg(draw("phantom_yaw_deg"))
    mu_w, mu_pl = draw("mu_water_per_mm"), draw("mu_plastic_per_mm")
    stand_h = draw("stand_height_mm")
    floor_y = pc[1] + edge / 2.0 + stand_h           # inner floor of the tank (+y is down)
    W, L, H = draw("tank_inner_width_mm") / 2.0, draw("tank_inner_length_mm") / 2.0, draw("tank_inner_height_mm")
    wall = draw("tank_wall_mm")
    tx, tzc = pc[0] + draw("tank_shift_mm"), pc[2] + draw("tank_shift_mm")
    fill = draw("water_fill")
    water_top = floor_y - fill * H

    prims: list[Primitive] = []
    table_top = floor_y + wall
    prims.append(_table(draw, table_top, tx))
    outer = Box([tx, floor_y - H / 2.0 + wall / 2.0, tzc], [W + wall, (H + wall) / 2.0, L + wall])
    inner_open = Box([tx, floor_y - H / 2.0 - 25.0, tzc], [W, H / 2.0 + 25.0, L])   # open at the top
    prims.append(Difference(outer, inner_open, mu_per_mm=mu_pl, name="tank"))
    prims.append(Box([tx, (floor_y + water_top) / 2.0, tzc], [W, (floor_y - water_top) / 2.0, L],
                     mu_per_mm=mu_w, name="water"))
    sw = draw("stand_half_width_mm")
    prims.append(Box([pc[0], floor_y - stand_h / 2.0, pc[2]], [sw, stand_h / 2.0, sw], R_ph,
                     mu_per_mm=mu_pl - mu_w, name="phantom stand"))
    half = edge / 2.0
    prims.append(Box(pc, [half, half, half], R_ph, mu_per_mm=draw("agarose_delta_mu"), name="agarose phantom"))
    layered = bool(rng.random() < p.layered_probability)
    layer = draw("layer_mm")
    mu_ba = draw("barium_delta_mu")
    if layered:
        # Alternating barium / plain layers, stacked vertically as poured. `y` is the upper (+y,
        # table-side) face of a barium layer in phantom coordinates; the first one starts at a
        # random phase, possibly partly outside the cube (clipped).
        y = half + layer * draw.uniform(0.0, 2.0)
        while y > -half:
            y_hi, y_lo = min(y, half), max(y - layer, -half)
            if y_hi - y_lo > 0.2:
                c_local = np.array([0.0, (y_hi + y_lo) / 2.0, 0.0])
                prims.append(Box(pc + R_ph @ c_local, [half, (y_hi - y_lo) / 2.0, half], R_ph,
                                 mu_per_mm=mu_ba, name="barium layer"))
            y -= 2.0 * layer
    meta = dict(draw.drawn)
    meta.update(layered=layered, phantom_center_mm=pc.tolist(), water_top_y_mm=water_top,
                tank_floor_y_mm=floor_y, table_top_y_mm=table_top, n_primitives=len(prims))
    return Anatomy(tuple(prims), name="random phantom set-up", kind="phantom", meta=meta)


def random_background(rng: np.random.Generator, kind: str = "abdomen") -> Anatomy:
    """A random scene of ``kind``: ``"abdomen"``, ``"phantom"``, or ``"mixed"`` (abdomen with
    probability 156/212, the paper's animal-to-phantom image ratio of §III-A, else phantom)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if kind == "mixed":
        kind = "abdomen" if rng.random() < MIXED_ABDOMEN_PROBABILITY else "phantom"
    if kind == "abdomen":
        return random_abdomen(rng)
    if kind == "phantom":
        return random_phantom_setup(rng)
    raise ValueError(f"kind must be 'abdomen', 'phantom' or 'mixed', got {kind!r}")
