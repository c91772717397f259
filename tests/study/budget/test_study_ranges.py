"""The sources without a measurement run at both ends of their range on lab 0: only that source's
magnitude moves, frames are shared where the source leaves them, and the bands are lab 0's
figures at each end."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from histostudy.imaging import default_biplane
from histostudy.study import budget as B
from histostudy.study.budget import _ranges
from histostudy.study.budget._labs import frames_alike, run_labs
from histostudy.study.budget._ranges import range_bands, range_labs
from histostudy.study.budget._run import BudgetSetup
from histostudy.study.budget._section import budget_seeds
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.study.targeting.setup import TargetingStudyConfig
from histostudy.transducer import TransducerModel


def _setup(*sources, n_experiments=1):
    model = TransducerModel.build(spacing_mm=0.47)
    seeds = budget_seeds(13)
    default = B.LabErrorModel()
    lab_model = dataclasses.replace(default.off(), **{s: getattr(default, s) for s in sources})
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    views = [v.scaled(0.5) for v in default_biplane()]  # half resolution: the runs compare on the same views
    lab0 = B.draw_lab(lab_model, seeds.lab, physical=physical, views=views, physical_seed=seeds.physical)
    pose = PoseStudyConfig(n_experiments=n_experiments, modes=("fast",), track=False, n_splats=2, background="phantom")
    targeting = TargetingStudyConfig(n_experiments=n_experiments, n_splats=2, background="none", bias_correction=False)
    return dataclasses.replace(BudgetSetup(lab0, pose, targeting, model, model), seeds=seeds)


def test_only_the_swept_source_moves_and_frames_are_kept_where_it_leaves_them():
    setup = _setup("manufacturing", "bubble_offset", "projection")
    lab0 = setup.lab
    labs = range_labs(setup, ["bubble_offset", "manufacturing"])
    assert [(s, e) for s, e, _, _ in labs] == [("bubble_offset", "low"), ("bubble_offset", "high"),
                                               ("manufacturing", "low"), ("manufacturing", "high")]
    ref = B.SOURCE_REFERENCES["bubble_offset"]
    for _, end, value, lab in labs[:2]:
        assert value == getattr(ref, end)
        np.testing.assert_allclose(lab.bubble_offset_mm, lab0.bubble_offset_mm * value / ref.value, rtol=1e-12)
        assert lab.physical is lab0.physical and lab.frame_views is lab0.frame_views  # shared frames
        assert all(np.array_equal(a.P, b.P) for a, b in zip(lab.estimator_views, lab0.estimator_views))
    man = B.SOURCE_REFERENCES["manufacturing"]
    # the focal point's distance from the digital model's (lab_magnitudes' measure), scaled with the tolerances
    low, high = (np.linalg.norm(lab.physical.focal_point_mm) for *_, lab in labs[2:])
    at_default = np.linalg.norm(lab0.physical.focal_point_mm)
    assert low == pytest.approx(at_default * man.low / man.value, rel=0.05)
    assert high == pytest.approx(at_default * man.high / man.value, rel=0.05)
    assert all(np.array_equal(lab.bubble_offset_mm, lab0.bubble_offset_mm) for *_, lab in labs[2:])
    with pytest.raises(ValueError, match="sources must name sources on in the lab model.*'gantry_sag'"):
        range_labs(setup, ["gantry_sag"])
    with pytest.raises(ValueError, match="each at most once"):
        range_labs(setup, ["bubble_offset", "bubble_offset"])


def test_run_ranges_shares_what_it_can_and_labels_each_run(monkeypatch):
    setup = _setup("gantry_sag", "bubble_offset")
    calls = []

    def fake_run_labs(budget_setup, labs, *, seed, indices, executor, centre_only):
        assert centre_only  # the bands read the centres' errors only
        calls.append((list(indices), labs, executor))
        rows = [{"lab": k, "study": s, "experiment": 0, "configuration": "lab"} for k in indices
                for s in ("pose", "targeting")]
        return pd.DataFrame(rows)

    monkeypatch.setattr(_ranges, "run_labs", fake_run_labs)
    out = B.run_ranges(setup, ["gantry_sag", "bubble_offset"], executor="local:1")
    # bubble_offset's two labs (3, 4) run together on lab 0's frames; gantry_sag's (1, 2) apart
    assert [c[0] for c in calls] == [[3, 4], [1, 2]] and {c[2] for c in calls} == {"local:1"}
    assert all(lab.frame_views is setup.lab.frame_views for lab in calls[0][1])
    assert list(out["source"].drop_duplicates()) == ["gantry_sag", "bubble_offset"]
    assert list(out.drop_duplicates("lab")["end"]) == ["low", "high", "low", "high"]


def _records(lab, err, configuration=None):
    rows = []
    for study, prefix in (("pose", "centre_err_"), ("targeting", "err_")):
        for e, sign in enumerate((1.0, -1.0)):
            vec = np.array(err) * (1.0 + 0.1 * sign)
            row = {"lab": lab, "study": study, "experiment": e, **{f"{prefix}{d}": v for d, v in
                                                                   zip(("depth", "tb", "lr"), vec)},
                   f"{prefix}euclidean": float(np.linalg.norm(vec))}
            if configuration:
                row["configuration"] = configuration
            rows.append(row)
    return rows


def _range_records(source, low_err, high_err):
    """run_ranges' rows for ``source``: lab 1 at the low end (value 0), lab 2 at the high end (value 2)."""
    ranges = pd.DataFrame(_records(1, low_err) + _records(2, high_err))
    ranges.insert(0, "value", ranges["lab"].map({1: 0.0, 2: 2.0}))
    ranges.insert(0, "end", ranges["lab"].map({1: "low", 2: "high"}))
    ranges.insert(0, "source", source)
    return ranges


def test_range_bands_are_lab_zero_at_each_end():
    ranges = _range_records("bubble_offset", [0.5, 0, 0], [2.0, 0, 0])
    budget = pd.DataFrame(_records(None, [1.0, 0, 0], "lab") + _records(None, [9.0, 0, 0],
                                                                        "baseline")).drop(columns="lab")
    bands = range_bands(ranges, budget).set_index("study")
    assert list(bands.index) == ["pose", "targeting"]
    assert bands.loc["pose", "at_low_mm"] == pytest.approx(0.5) and bands.loc["pose",
                                                                              "at_high_mm"] == pytest.approx(2.0)
    assert bands.loc["pose", "at_default_mm"] == pytest.approx(1.0)  # the "lab" configuration, not the baseline
    assert bands.loc["targeting", "band_mm"] == pytest.approx(1.5)
    assert bands.loc["pose", "status"] == "swept" and bands.loc["pose",
                                                                "high"] == B.SOURCE_REFERENCES["bubble_offset"].high


def test_a_band_spans_the_default_where_the_source_is_not_monotone():
    ranges = _range_records("gantry_sag", [1.5, 0, 0], [1.5, 0, 0])
    budget = pd.DataFrame(_records(None, [1.0, 0, 0], "lab")).drop(columns="lab")
    bands = range_bands(ranges, budget).set_index("study")
    assert bands.loc["pose", "at_low_mm"] == pytest.approx(bands.loc["pose", "at_high_mm"])
    assert bands.loc["pose", "band_mm"] == pytest.approx(0.5)  # both ends 1.5 mm, the default 1.0 mm


@pytest.mark.slow
def test_a_range_run_is_the_lab_run_alone():
    # lab 0's arm has its kinematic error: the range labs keep it, so their targeting runs share frames too
    setup = _setup("bubble_offset", "projection", "robot_accuracy")
    labs = [lab for *_, lab in range_labs(setup, ["bubble_offset"])]
    assert frames_alike(labs, "targeting")  # one task for both ends: the frames rendered once
    out = B.run_ranges(setup, ["bubble_offset"])
    high = labs[1]
    alone = run_labs(setup, [high], seed=setup.seeds.study, indices=[2], share=False, centre_only=True)
    got = out[out["lab"] == 2].drop(columns=["source", "end", "value"]).reset_index(drop=True)
    pd.testing.assert_frame_equal(got[alone.columns], alone, check_exact=True, check_dtype=False)
    # the bubble cloud lies further off at the high end: the targeting error grows
    err = out[out["study"] == "targeting"].groupby("end")["err_euclidean"].mean()
    assert err["high"] > err["low"]
