"""Random abdomen and phantom scenes, the backgrounds of the hybrid fluoroscopy frames (§II-B.2, §II-D):
a random analytic 3-D scene projected exactly, so that both biplane views see one body. World frame:
CBCT, LPS, mm, origin at the isocentre (docs/imaging.md, "The scenes")."""

from __future__ import annotations

from typing import Any

import numpy as np

from ._abdomen_parts import (
    _body_layers,
    _bowel_gas,
    _organs,
    _place_body,
    _ribs,
    _rot_y_deg,
    _stomach_gas,
    _vertebral_column,
)
from ._csg import Difference
from ._params import AbdomenSpec, PhantomSceneSpec, _Draw, _with_overrides
from ._scene import Anatomy
from ._shapes import Box, Primitive

__all__ = [
    "MIXED_ABDOMEN_PROBABILITY",
    "random_abdomen",
    "random_background",
    "random_phantom_setup",
]

#: Probability of an animal (abdomen) background in ``kind="mixed"``: the paper's segmentation
#: evaluation had 156 animal and 56 phantom images (§III-A).
MIXED_ABDOMEN_PROBABILITY = 156.0 / (156.0 + 56.0)


def _table(draw: _Draw, table_top_y: float, center_x: float) -> Box:
    """The carbon-fibre patient table (§II-D, Fig. 4A) as a slab whose top lies at world
    ``table_top_y`` (mm, +y down), centred at ``center_x``; thickness, width, mu [1/mm] drawn."""
    thick = draw("table_thickness_mm")
    return Box(np.array([center_x, table_top_y + thick / 2.0, 0.0]),
               np.array([draw("table_width_mm") / 2.0, thick / 2.0, 1000.0]), mu_per_mm=draw("table_mu_per_mm"),
               name="table")


def random_abdomen(rng: np.random.Generator, params: AbdomenSpec | None = None, **overrides) -> Anatomy:
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
        params: the ranges to draw from; default :class:`AbdomenSpec`.
        **overrides: fields of :class:`AbdomenSpec` to replace, a range ``(lo, hi)`` or a number.
    """
    p = _with_overrides(AbdomenSpec, params, overrides)
    draw = _Draw(rng, p)
    body = _place_body(draw)
    local, tissue = _body_layers(draw, body)
    organs, stomach, spine_x, spine_y = _organs(draw, tissue)
    local += organs
    # Bounding balls of the negative primitives and of what they must not overlap: gas may only
    # replace tissue that is there, so that no line integral (or attenuation) becomes negative.
    gas_balls: list[tuple[np.ndarray, float]] = []
    avoid: list[tuple[np.ndarray, float]] = [(stomach.center_mm, float(stomach.semi_axes_mm.max()))]
    stomach_gas = _stomach_gas(draw, p, stomach, tissue.mu_soft)
    if stomach_gas is not None:
        local.append(stomach_gas[0])
        gas_balls.append(stomach_gas[1])
    column, b_vb = _vertebral_column(draw, tissue, spine_x, spine_y)
    local += column
    local += _ribs(draw, tissue, body, spine_x, spine_y, b_vb)
    local += _bowel_gas(draw, p, tissue, gas_balls, avoid)

    prims: list[Primitive] = [q.transformed(body.T) for q in local]
    body_outer = prims[0]
    # --- table and water bath (world frame, horizontal) -----------------------------------------------
    table_top = body.cy + body.back_y
    prims.append(_table(draw, table_top, body.t[0] + draw("table_shift_x_mm")))
    skin_y = -body.depth
    meta: dict[str, Any] = {}
    if rng.random() < p.bath_probability:
        prims += _water_bath(draw, body_outer, skin_y, meta)
    meta.update(draw.drawn)
    meta.update(anterior_skin_y_mm=skin_y, table_top_y_mm=table_top, body_center_mm=body.t.tolist(),
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
    water = Box(np.array([bx, (y_bottom + y_top) / 2.0, bz]), np.array([bw, (y_bottom - y_top) / 2.0, bl]))
    out: list[Primitive] = [Difference(water, body_outer, mu_per_mm=mu_w, name="water bath")]
    wall_top = y_top - 20.0                     # the walls stand a little above the water
    wall_half_y, wall_cy = (y_bottom - wall_top) / 2.0, (y_bottom + wall_top) / 2.0
    for sgn in (-1.0, 1.0):
        walls = [Box(np.array([bx + sgn * (bw + wall / 2.0), wall_cy, bz]),
                     np.array([wall / 2.0, wall_half_y, bl + wall])),
                 Box(np.array([bx, wall_cy, bz + sgn * (bl + wall / 2.0)]), np.array([bw, wall_half_y, wall / 2.0]))]
        out += [Difference(w, body_outer, mu_per_mm=mu_pl, name="bath wall") for w in walls]
    meta.update(bath_top_y_mm=y_top, bath_bottom_y_mm=y_bottom, bath_center_mm=[bx, (y_bottom + y_top) / 2.0, bz],
                bath_half_sizes_mm=[bw, (y_bottom - y_top) / 2.0, bl])
    return out


def random_phantom_setup(rng: np.random.Generator, params: PhantomSceneSpec | None = None, **overrides) -> Anatomy:
    """The phantom studies' scene (§II-D, Fig. 4A): an agarose phantom in a water tank on the table.

    A ``phantom_edge_mm`` (5 cm) agarose cube, layered with barium when drawn (§II-D.1,
    ~4 mm layers stacked vertically as poured), stands on a plastic block in a degassed water
    tank (plastic walls, open top) on the carbon-fibre table. The phantom centre lies within
    ``phantom_offset_mm`` of the isocentre, where the transducer's focal point is aimed.
    World frame: CBCT, mm, LPS.

    Args:
        rng: the Generator every random draw comes from.
        params: the ranges to draw from; default :class:`PhantomSceneSpec`.
        **overrides: fields of :class:`PhantomSceneSpec` to replace, a range or a number.
    """
    p = _with_overrides(PhantomSceneSpec, params, overrides)
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
    outer = Box(np.array([tx, floor_y - H / 2.0 + wall / 2.0, tzc]), np.array([W + wall, (H + wall) / 2.0, L + wall]))
    # open at the top
    inner_open = Box(np.array([tx, floor_y - H / 2.0 - 25.0, tzc]), np.array([W, H / 2.0 + 25.0, L]))
    prims.append(Difference(outer, inner_open, mu_per_mm=mu_pl, name="tank"))
    prims.append(Box(np.array([tx, (floor_y + water_top) / 2.0, tzc]), np.array([W, (floor_y - water_top) / 2.0, L]),
                     mu_per_mm=mu_w, name="water"))
    sw = draw("stand_half_width_mm")
    prims.append(Box(np.array([pc[0], floor_y - stand_h / 2.0, pc[2]]), np.array([sw, stand_h / 2.0, sw]), R_ph,
                     mu_per_mm=mu_pl - mu_w, name="phantom stand"))
    half = edge / 2.0
    prims.append(Box(pc, np.array([half, half, half]), R_ph, mu_per_mm=draw("agarose_delta_mu"),
                     name="agarose phantom"))
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
                prims.append(Box(pc + R_ph @ c_local, np.array([half, (y_hi - y_lo) / 2.0, half]), R_ph,
                                 mu_per_mm=mu_ba, name="barium layer"))
            y -= 2.0 * layer
    meta = dict(draw.drawn)
    meta.update(layered=layered, phantom_center_mm=pc.tolist(), water_top_y_mm=water_top,
                tank_floor_y_mm=floor_y, table_top_y_mm=table_top, n_primitives=len(prims))
    return Anatomy(tuple(prims), name="random phantom set-up", kind="phantom", meta=meta)


def random_background(rng: np.random.Generator, kind: str = "abdomen") -> Anatomy:
    """A random background scene (§II-B.2).

    Args:
        rng: the Generator the scene is drawn from.
        kind: ``"abdomen"``, ``"phantom"``, or ``"mixed"`` (abdomen with probability 156/212, the
            paper's animal-to-phantom image ratio of §III-A, else phantom).

    Returns:
        The scene, an :class:`~histostudy.imaging.anatomy.Anatomy`.

    Raises:
        TypeError: ``rng`` is not a ``numpy.random.Generator``.
        ValueError: ``kind`` is none of the three.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if kind == "mixed":
        kind = "abdomen" if rng.random() < MIXED_ABDOMEN_PROBABILITY else "phantom"
    if kind == "abdomen":
        return random_abdomen(rng)
    if kind == "phantom":
        return random_phantom_setup(rng)
    raise ValueError(f"kind must be 'abdomen', 'phantom' or 'mixed', got {kind!r}")
