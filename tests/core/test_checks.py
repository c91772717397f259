"""histostudy.core.checks: what each check accepts, and the message a refusal gives."""

import math

import numpy as np
import pytest

from histostudy.core import check_count, check_items, check_positive, check_unit_fraction, is_finite_real, is_real


@pytest.mark.parametrize("value, real, finite", [
    (1, True, True), (2.5, True, True), (np.float32(3), True, True), (np.int64(4), True, True),
    (math.nan, True, False), (-math.inf, True, False), (True, False, False), ("1", False, False),
    (None, False, False), (np.array([1.0]), False, False), (1 + 0j, False, False),
])
def test_real_and_finite(value, real, finite):
    assert is_real(value) is real and is_finite_real(value) is finite


def test_check_positive_returns_a_float_and_names_the_argument_its_value_and_the_bound():
    assert check_positive(np.int32(3), "radius_mm") == 3.0 and type(check_positive(2, "x")) is float
    assert check_positive(0, "dwell_s", allow_zero=True) == 0.0
    for bad in (0, -1.0, math.nan, math.inf, True, "2", None):
        expected = r"^radius_mm must be a finite number > 0 mm, got " + repr(bad).replace("(", r"\(")
        with pytest.raises(ValueError, match=expected):
            check_positive(bad, "radius_mm", unit="mm")
    with pytest.raises(ValueError, match=r"dwell_s must be a finite number >= 0, got -0.1"):
        check_positive(-0.1, "dwell_s", allow_zero=True)


def test_check_count():
    assert check_count(np.int64(5), "n") == 5 and check_count(0, "n", minimum=0) == 0
    for bad in (0, 2.0, True, "3", -1):
        with pytest.raises(ValueError, match=rf"^n must be an integer >= 1, got {bad!r}"):
            check_count(bad, "n")


@pytest.mark.parametrize("scale, k", [(1, 1), (0.5, 2), (0.25, 4), (np.float32(0.125), 8), (1 / 3, 3)])
def test_unit_fractions_give_their_reduction(scale, k):
    assert check_unit_fraction(scale) == k


@pytest.mark.parametrize("scale", [0, -0.5, 0.3, 2, math.nan, "half", None, True])
def test_other_scales_are_refused_by_name(scale):
    with pytest.raises(ValueError, match=r"label_scale must be 1/k for an integer k >= 1"):
        check_unit_fraction(scale, "label_scale")


def test_check_items_takes_one_item_or_many_and_names_the_bad_index():
    assert check_items(3, "counts", int) == [3] and check_items((1, 2), "counts", int) == [1, 2]
    with pytest.raises(ValueError, match=r"^counts must hold at least one int, got none$"):
        check_items([], "counts", int)
    with pytest.raises(TypeError, match=r"^counts\[1\] must be a an integer, got str: 'x'$"):
        check_items([1, "x"], "counts", int, type_name="an integer")
    with pytest.raises(TypeError, match=r"counts\[0\] must be a builtins.int, got float"):
        check_items([1.5], "counts", int)
