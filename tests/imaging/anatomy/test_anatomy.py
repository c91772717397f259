"""Tests of histostudy.imaging.anatomy._random (and its ranges, _params): the random abdomen and phantom
set-up scenes, their seeding, landmarks, overrides and plausible line integrals."""

import numpy as np
import pytest

from histostudy.imaging import Anatomy, View, default_biplane, random_background
from histostudy.imaging.anatomy._params import AbdomenSpec
from histostudy.imaging.anatomy._random import MIXED_ABDOMEN_PROBABILITY, random_abdomen, random_phantom_setup

SMALL = dict(shape=(96, 124), pixel_mm=3.08)     # a 1240x960 detector binned 10x


# --- random scenes -------------------------------------------------------------------------------


def test_same_seed_same_image_other_seed_other_image():
    view = View.from_gantry(-45.0, **SMALL)
    for kind in ("abdomen", "phantom"):
        a = random_background(np.random.default_rng(5), kind).line_integrals(view)
        b = random_background(np.random.default_rng(5), kind).line_integrals(view)
        c = random_background(np.random.default_rng(6), kind).line_integrals(view)
        assert np.array_equal(a, b)
        assert np.abs(a - c).max() > 0.05


def test_abdomen_line_integrals_are_plausible_and_non_negative():
    views = default_biplane(shape=(96, 124), pixel_mm=3.08)
    medians = []
    for seed in range(4):
        anatomy = random_abdomen(np.random.default_rng(seed))
        body_only = Anatomy(tuple(p for p in anatomy.primitives if p.name == "body (fat)"))
        no_bath = Anatomy(tuple(p for p in anatomy.primitives if "bath" not in p.name and p.name != "table"))
        for view in views:
            img = anatomy.line_integrals(view)
            assert np.all(np.isfinite(img)) and img.min() >= 0.0
            in_body = body_only.line_integrals(view) > 0.5
            assert in_body.mean() > 0.5
            body = no_bath.line_integrals(view)[in_body]
            assert 2.0 < np.median(body) < 8.0 and body.max() < 12.0
            medians.append(np.median(img[in_body]))
    assert 3.0 < np.median(medians) < 10.0          # body plus water bath and table


def test_abdomen_attenuation_is_never_negative():
    # Gas pockets only replace tissue that is there: no point has a negative attenuation.
    rng = np.random.default_rng(0)
    for seed in range(3):
        anatomy = random_abdomen(np.random.default_rng(seed), gas_pockets=9)
        pts = rng.uniform([-200.0, -250.0, -200.0], [200.0, 200.0, 200.0], size=(20_000, 3))
        gas = [p for p in anatomy.primitives if "gas" in p.name]
        assert gas
        # Points in and around each gas pocket, out to its edges.
        near_gas = np.concatenate([p.center_mm + rng.normal(0, p.semi_axes_mm.max(), size=(1500, 3)) for p in gas])
        mu = anatomy.attenuation(np.vstack([pts, near_gas]))
        assert mu.min() >= -1e-12
        assert mu.max() < 0.1                       # overlapping bones stay bone-like


def test_abdomen_landmarks_and_overrides():
    anatomy = random_abdomen(np.random.default_rng(8), target_depth_mm=80.0, body_shift_x_mm=0.0,
                             body_yaw_deg=0.0, bath_probability=0.0)
    assert anatomy.kind == "abdomen"
    assert anatomy.meta["target_depth_mm"] == 80.0
    assert not any("bath" in p.name for p in anatomy.primitives)
    # The skin is 80 mm anterior of the isocentre, the table under the back.
    assert anatomy.attenuation([[0.0, -79.0, 0.0]])[0] > 0.015
    assert anatomy.attenuation([[0.0, -81.0, 0.0]])[0] == 0.0
    top = anatomy.meta["table_top_y_mm"]
    assert anatomy.attenuation([[0.0, top + 5.0, 0.0]])[0] > 0.0
    with_bath = random_abdomen(np.random.default_rng(8))
    y_top = with_bath.meta["bath_top_y_mm"]
    c = with_bath.meta["bath_center_mm"]
    assert with_bath.attenuation([[c[0], y_top + 5.0, c[2]]])[0] == pytest.approx(with_bath.meta["mu_water_per_mm"])


def test_params_are_named_ranges_that_overrides_replace():
    params = AbdomenSpec(fat_mm=12.0, liver_semi_axes_mm=(40.0, (30.0, 35.0), 60.0))
    assert params.fat_mm == (12.0, 12.0)
    assert params.liver_semi_axes_mm == ((40.0, 40.0), (30.0, 35.0), (60.0, 60.0))
    anatomy = random_abdomen(np.random.default_rng(3), params, rib_pairs=0, gas_pockets=0,
                             stomach_gas_probability=0.0)
    liver = [p for p in anatomy.primitives if p.name == "liver"][0]
    assert liver.semi_axes_mm[0] == pytest.approx(40.0) and 30.0 <= liver.semi_axes_mm[1] <= 35.0
    assert not any(p.name in ("rib", "bowel gas", "stomach gas") for p in anatomy.primitives)
    assert anatomy.meta["fat_mm"] == 12.0
    with pytest.raises(ValueError, match="liver_semi_axes_mm must be 3 ranges"):
        AbdomenSpec(liver_semi_axes_mm=(40.0, 50.0))
    with pytest.raises(ValueError, match="rib_pairs must be a range of non-negative integers"):
        AbdomenSpec(rib_pairs=(2.5, 4))
    with pytest.raises(ValueError, match="bath_probability must be a probability"):
        AbdomenSpec(bath_probability=1.5)


def test_phantom_setup_has_a_layered_cube_near_the_isocentre():
    anatomy = random_phantom_setup(np.random.default_rng(9))
    assert anatomy.kind == "phantom" and anatomy.meta["layered"]
    pc = np.array(anatomy.meta["phantom_center_mm"])
    assert np.all(np.abs(pc) <= 10.0)
    # Along the vertical through the phantom: layers of two attenuations alternate inside it.
    y = np.linspace(-24.0, 24.0, 400)
    mu = anatomy.attenuation(np.column_stack([np.full_like(y, pc[0]), pc[1] + y, np.full_like(y, pc[2])]))
    levels = np.unique(np.round(mu, 6))
    assert len(levels) == 2 and levels[1] - levels[0] > 0.003
    assert np.count_nonzero(np.diff(mu) != 0) >= 8
    plain = random_phantom_setup(np.random.default_rng(9), layered_probability=0.0)
    assert not any(p.name == "barium layer" for p in plain.primitives)
    img = anatomy.line_integrals(View.from_gantry(-45.0, **SMALL))
    assert img.min() >= 0.0 and 2.0 < np.median(img) < 12.0


def test_mixed_kind_follows_the_papers_animal_to_phantom_ratio():
    assert MIXED_ABDOMEN_PROBABILITY == pytest.approx(156 / 212)
    kinds = []
    for seed in range(30):
        expected = "abdomen" if np.random.default_rng(seed).random() < 156 / 212 else "phantom"
        kind = random_background(np.random.default_rng(seed), "mixed").kind
        assert kind == expected
        kinds.append(kind)
    assert set(kinds) == {"abdomen", "phantom"}


# --- errors --------------------------------------------------------------------------------------


def test_bad_input_errors_name_the_argument():
    with pytest.raises(ValueError, match="kind must be 'abdomen', 'phantom' or 'mixed', got 'pig'"):
        random_background(np.random.default_rng(0), "pig")
    with pytest.raises(TypeError, match="rng"):
        random_abdomen(42)
    with pytest.raises(ValueError, match="unknown AbdomenSpec field"):
        random_abdomen(np.random.default_rng(0), body_widht_mm=(300, 350))
    with pytest.raises(ValueError, match="fat_mm"):
        AbdomenSpec(fat_mm=(30.0, 10.0))
