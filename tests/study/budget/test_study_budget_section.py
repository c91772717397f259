"""Notebook 07's section interface (histostudy.study.budget): its parameters checked by name, the set-up
made from them, and the parts recorded from the budget's records."""


import pandas as pd
import pytest

from histostudy.study import budget as B
from histostudy.study.budget import _section as budget_notebook
from histostudy.study.budget._section import (
    RECORDED_PARAMETERS,
    budget_seeds,
    lab_model_from_parameters,
    prepare_budget,
    sources_table,
    stand_ins,
)

#: The parameters cell of notebooks/07_error_budget.ipynb as stored (its defaults).
DEFAULTS = dict(photons_per_pixel=50000.0, n_splats=16, splat_sigma_mm=0.5, splat_device="cpu", pose_spacing_mm=0.47,
                render_spacing_mm=0.25, background="phantom", pose_experiments=1, targeting_experiments=1,
                learned_stages=True, sources=("manufacturing", "bubble_offset", "projection", "gantry_sag",
                                              "registration", "annotation", "robot", "phantom_motion"),
                n_labs=3, range_sources=("bubble_offset",), scheduler="")


def test_the_parameters_are_the_notebooks_and_the_report_records_the_same_ones(notebook_parameters):
    cell = notebook_parameters("07_error_budget")
    params = B.BudgetSectionConfig.from_parameters(cell)
    assert {k: getattr(params, k) for k in DEFAULTS} == DEFAULTS  # sources kept as a tuple
    assert set(cell) - set(DEFAULTS) == {"profile", "seed", "output_dir"}
    assert list(params.recorded()) == list(RECORDED_PARAMETERS) == list(DEFAULTS)
    with pytest.raises(AttributeError):
        params.scheduler = "local:2"  # frozen


def test_missing_parameters_are_named():
    with pytest.raises(ValueError, match=r"parameters lack \['scheduler'\] \(notebook 07's"):
        B.BudgetSectionConfig.from_parameters({k: v for k, v in DEFAULTS.items() if k != "scheduler"})


@pytest.fixture(scope="module")
def setup():
    return B.prepare({**DEFAULTS, "render_spacing_mm": 0.47, "learned_stages": False, "sources": ["robot"],
                      "range_sources": [],
                      "scheduler": "local:1"}, 7)


def test_prepare_is_prepare_budget_on_the_checked_parameters(setup):
    assert isinstance(setup.params, B.BudgetSectionConfig) and setup.params.sources == ("robot",)
    assert setup.seeds.study == budget_seeds(7).study
    assert setup.seeds.lab.generate_state(4).tolist() == budget_seeds(7).lab.generate_state(4).tolist()
    plain = prepare_budget(setup.params.recorded(), 7)
    assert (setup.pose_config, setup.targeting_config) == (plain.pose_config, plain.targeting_config)
    assert setup.lab.model == plain.lab.model == lab_model_from_parameters(["robot"])


def test_the_parts_of_a_budget(setup, monkeypatch, recording_timer):
    assert B.sources_part(setup).table("sources").equals(sources_table(setup.lab.model))
    calls = {}

    def fake_budget(budget_setup, *, seed, executor):
        calls.update(setup=budget_setup, seed=seed, executor=executor)
        return "records"

    monkeypatch.setattr(budget_notebook, "run_error_budget", fake_budget)
    monkeypatch.setattr(budget_notebook, "configuration_table", lambda records, study: pd.DataFrame({"study": [study]}))
    monkeypatch.setattr(budget_notebook, "budget_comparisons",
                        lambda records, labs: [dict(key="k", label="", ours=1.0, labs=labs)])
    timer, timed = recording_timer()

    run = B.budget_section(setup, timer=timer)
    assert timed == ["budget"] and calls == dict(setup=setup, seed=budget_seeds(7).study, executor="local:1")
    assert list(run.part.tables) == ["pose_configurations", "targeting_configurations"]
    assert run.pose_table["study"][0] == "pose" and run.targeting_table["study"][0] == "targeting"
    closing = B.closing_part(setup, run.records)
    assert closing.comparisons == (dict(key="k", label="", ours=1.0, labs=None),)
    assert closing.stand_ins == tuple(stand_ins())
    assert closing.texts[0].startswith("1 pose and 1 targeting experiment(s) per configuration, one lab (lab 0)")
    assert "median over" not in closing.texts[0]
    labs = pd.DataFrame({"lab": [0, 1, 2, 0, 1, 2], "study": ["pose"] * 3 + ["targeting"] * 3})
    many = B.closing_part(setup, run.records, labs)
    assert many.comparisons[0]["labs"] is labs and "the median over 3 labs" in many.texts[0]
