"""The agreement rule: the difference to the paper and its status (docs/report.md)."""

import pytest

from histostudy.reporting import PAPER, PaperValue
from histostudy.reporting.agreement import AGREES, DIFFERS, FAR_OFF, NOT_JUDGED, judge


def _row(ours, unit="deg", ours_text=None):
    return {"ours": ours, "unit": unit, "ours_text": ours_text or (f"{ours:.2f} {unit}" if isinstance(ours, float)
                                                                     else str(ours))}


MAE = PaperValue(1.06, 0.71, "deg", "§III")


@pytest.mark.parametrize("ours, status, n_sd", [(1.06, AGREES, 0.0), (1.77, AGREES, 1.0), (0.35, AGREES, 1.0),
                                                 (2.0, DIFFERS, 0.94 / 0.71), (3.19, DIFFERS, 3.0),
                                                 (24.63, FAR_OFF, 23.57 / 0.71)])
def test_status_from_the_paper_sd(ours, status, n_sd):
    a = judge(_row(ours), MAE)
    assert a.status == status and a.sd_based
    assert a.difference == pytest.approx(ours - 1.06)
    assert a.n_sd == pytest.approx(n_sd, abs=1e-9)


def test_far_off_is_flagged_in_the_summary_with_its_size():
    a = judge(_row(24.63), MAE)
    assert a.difference_text() == "+23.57 deg"
    assert a.summary() == "far off (33 SD above)"
    assert judge(_row(0.2), PaperValue(1.06, 0.2, "deg")).summary() == "far off (4.3 SD below)"
    assert judge(_row(1.5), MAE).summary() == "agrees (0.6 SD)"


def test_twin_sd_is_the_tolerance_of_a_number_printed_without_one():
    bias = PAPER["pose.center_bias.tb"]  # 0.30 mm in §III; Table II: 0.3 ± 0.6
    assert bias.sd is None and PAPER[bias.twin].sd == 0.6
    a = judge(_row(0.8, "mm"), bias, twin=PAPER[bias.twin])
    assert a.status == AGREES and a.tolerance == 0.6 and "Table II" in a.basis
    assert judge(_row(0.8, "mm"), bias).status == DIFFERS  # without the twin: the paper's rounding


def test_without_any_sd_the_paper_rounding_decides_and_nothing_is_far_off():
    radius = PaperValue(138.7, None, "mm", "§II-B.1")
    assert judge(_row(138.74, "mm"), radius).status == AGREES
    a = judge(_row(150.0, "mm"), radius)
    assert a.status == DIFFERS and a.n_sd is None and a.basis == "the paper gives no SD"
    assert judge({"ours": 4, "unit": "", "ours_text": "4"}, PAPER["seg.n_images"]).summary() == \
        "differs (the paper gives no SD)"


def test_difference_keeps_the_reproduced_decimals_and_never_reads_minus_zero():
    a = judge(_row(138.70001, "mm", "138.700 mm"), PaperValue(138.7, None, "mm"))
    assert a.difference_text() == "0.000 mm"
    assert judge(_row(1.0, "%", "1.0 %"), PaperValue(2.0, 1.0, "%")).difference_text() == "-1.0 %"


def test_units_degrees_alias_and_mismatch():
    assert judge(_row(1.06, "°"), MAE).status == AGREES
    a = judge(_row(1.06, "mm"), MAE)
    assert a.status == NOT_JUDGED and "units differ" in a.basis and a.difference is None


def test_intervals_and_bounds():
    ci = PAPER["seg.tukey_screws_vs_background_ci"]  # [7.7, 10.1]
    assert judge({"ours": "[9.0, 12.0]"}, ci).status == AGREES
    assert judge({"ours": "[10.5, 83.5]"}, ci).status == DIFFERS
    p = PAPER["seg.anova_p"]  # "< 1e-5"
    assert judge({"ours": "3.2e-07"}, p).status == AGREES
    a = judge({"ours": "0.006"}, p)
    assert a.status == DIFFERS and "misses" in a.basis


def test_missing_or_text_values_are_not_judged():
    assert judge({"ours": None, "unit": "%"}, PAPER["seg.global_accuracy"]).summary() == \
        "not judged: no reproduced number"
    assert judge({"ours": "not computed"}, PAPER["seg.anova_F"]).status == NOT_JUDGED
    assert judge({"ours": "-45°, +45° around PA"}, PAPER["carm.gantry_angles_deg"]).status == NOT_JUDGED
