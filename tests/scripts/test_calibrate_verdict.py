"""scripts/calibrate_verdict.py judges a rule as the verdict does, and offers today's rule among its
candidates."""

import pytest


@pytest.fixture(scope="module")
def script(load_script):
    return load_script("calibrate_verdict")


def test_a_rule_refuses_as_the_verdict_does(script):
    long_cheap = ({"A": 2.0, "B": 0.3}, {"A": 0.01, "B": 0.001})  # a flat valley: a long move, little gain
    short_dear = ({"A": 0.4, "B": 0.3}, {"A": 0.12, "B": 0.002})  # a short move that buys much
    assert script.refuses((1.5, None, None), *long_cheap) and not script.refuses((1.5, None, None), *short_dear)
    assert not script.refuses((1.5, 0.02, None), *long_cheap) and script.refuses((1.5, 0.005, None), *long_cheap)
    assert script.refuses((None, None, 0.05), *short_dear) and not script.refuses((None, None, 0.05), *long_cheap)
    assert not script.refuses((None, None, None), *short_dear)


def test_the_candidates_hold_today_s_rule_and_the_gain_bounds(script):
    rules = script.candidate_rules([0.001, 0.004, 0.01, 0.05])
    assert (1.5, None, None) in rules and (None, None, None) in rules
    assert (None, None, pytest.approx(0.055)) in rules
    assert all(r[1] is None or r[0] is not None for r in rules)  # a least gain qualifies a move bound
    assert len(set(rules)) == len(rules)
