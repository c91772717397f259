"""Notebook 07's many labs: the labs drawn from the set-up (lab 0 is its lab), labs 1.. run on the
set-up's seed and scheduler, lab 0 taken from the budget, and the parts recorded."""

import numpy as np
import pandas as pd
import pytest

from histostudy.study import budget as B
from histostudy.study.budget import _labs_section as _labs_notebook

#: A small notebook 07: two sources, three labs.
PARAMETERS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu", pose_spacing_mm=0.47,
                  render_spacing_mm=0.47, background="phantom", pose_experiments=1, targeting_experiments=1,
                  learned_stages=False, sources=["bubble_offset", "projection"], n_labs=3, range_sources=["projection"],
                  scheduler="local:1")


@pytest.fixture(scope="module")
def setup():
    return B.prepare(PARAMETERS, 7)


def _records(labs, study, rng):
    prefix = "centre_err_" if study == "pose" else "err_"
    rows = []
    for lab in labs:
        for e in range(3):
            err = rng.normal(0.0, 1.0, 3)
            rows.append({"study": study, "lab": lab, "configuration": "lab", "experiment": e,
                         **{f"{prefix}{d}": v for d, v in zip(("depth", "tb", "lr"), err)},
                         f"{prefix}euclidean": float(np.linalg.norm(err))})
    return rows


def test_the_labs_of_the_setup_and_their_part(setup, monkeypatch, recording_timer):
    labs = B.prepare_labs(setup)
    assert len(labs) == 3 and np.array_equal(labs[0].bubble_offset_mm, setup.lab.bubble_offset_mm)
    assert all(np.array_equal(a.P, b.P) for a, b in zip(labs[0].estimator_views, setup.lab.estimator_views))
    rng = np.random.default_rng(0)
    budget = pd.DataFrame(_records([0], "pose", rng) + _records([0], "targeting", rng))
    budget = budget.drop(columns="lab")
    budget = pd.concat([budget, budget.assign(configuration="baseline")], ignore_index=True)
    calls = {}

    def fake_run_labs(budget_setup, more, *, seed, indices, executor):
        calls.update(labs=more, seed=seed, indices=list(indices), executor=executor)
        out = pd.DataFrame(_records([1, 2], "pose", rng) + _records([1, 2], "targeting", rng))
        out.attrs.update(frames=(14, 28), segmentations=(14, 28))
        return out

    monkeypatch.setattr(_labs_notebook, "run_labs", fake_run_labs)
    timer, timed = recording_timer()
    many = B.labs_section(setup, labs, budget, timer=timer)
    assert timed == ["labs"] and calls["labs"] == labs[1:] and calls["indices"] == [1, 2]
    assert calls["seed"] == setup.seeds.study and calls["executor"] == "local:1"
    assert sorted(many.stats["lab"].unique()) == [0, 1, 2]
    lab0 = many.stats.set_index(["lab", "study"]).loc[(0, "pose")]
    assert lab0["bias_lr_mm"] == pytest.approx(budget.query("configuration == 'lab' and study == 'pose'")
                                               ["centre_err_lr"].mean())
    assert list(many.part.tables) == ["labs_vs_paper", "bias_scatter", "signs", "movers"]
    assert list(many.part.figures) == ["labs"] and many.part.values["labs_frames_made_shared"] == [14, 28]
    assert "Frames rendered 14, shared 28" in many.part.texts[0]
    assert set(many.magnitudes.columns) == {"lab", "bubble_offset", "projection"}
