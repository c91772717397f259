"""A training campaign: steps that resume the run in the cache, a machine without the cache that
restarts from the committed float16 weights, the ledger's accounting, and definitions or arguments
that are wrong."""

import json
from pathlib import Path

import numpy as np
import pytest

from histostudy.cli import main
from histostudy.learning import MODELS_DIR
from histostudy.learning.checkpoints import load_checkpoint
from histostudy.study.campaign import (
    campaign_run_dir,
    compare_restart_weights,
    ledger_table,
    load_campaign,
    read_ledger,
    run_campaign_step,
)

TINY = """
description = "a tiny U-Net on a handful of frames"
seed = 7

[training]
task = "segmentation"
network = { arch = "unet", base_width = 4, depth = 2 }
scale = 0.5
crop = 64
n_train = 5
n_val = 2
batch_size = 5
optimizer = "adam"
patience = 50
max_epochs = 50
render = { render_spacing_mm = 0.47, label_spacing_mm = 0.47, n_splats = 2, splat_device = "cpu" }

[evaluation]
frames = 2
render = { render_spacing_mm = 0.47, label_spacing_mm = 0.47, n_splats = 2, splat_device = "cpu" }
"""


def _floats(values) -> np.ndarray:
    """A ledger's per-frame figures (None where undefined) as floats (NaN)."""
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def _campaign(root: Path, text: str = TINY, name: str = "tiny") -> Path:
    (root / name).mkdir(parents=True)
    (root / name / "campaign.toml").write_text(text)
    return root


@pytest.mark.slow
def test_steps_resume_then_a_machine_without_the_cache_restarts_from_the_committed_weights(tmp_path):
    campaigns, cache = _campaign(tmp_path / "campaigns"), tmp_path / "cache"
    spec = load_campaign("tiny", campaigns)
    first = run_campaign_step(spec, 0.1, eval_seed=11, cache_dir=cache, log=lambda m: None)
    assert (first["run"], first["start"], first["steps_before"]) == (1, "fresh", 0)
    assert first["steps_after"] > 0 and first["frames_rendered"] == 7  # 5 training and 2 validation frames
    assert first["cpu_hours"] > 0 and first["held_out"]["seed"] == 11 and first["held_out"]["frames"] == 2
    for metrics in first["held_out"]["per_class"].values():
        assert all(v is None or 0.0 <= v <= 100.0 for v in metrics.values())  # None: undefined (NaN)
    # the shipped U-Net on the same frames, and the two compared frame by frame
    baseline = first["baseline"]
    assert baseline["weights"] == "data/models/unet_standard.safetensors"
    assert baseline["held_out"]["seed"] == 11 and baseline["held_out"]["frames"] == 2
    assert baseline["sha256"] == json.loads((MODELS_DIR / "unet_standard.json").read_text())["sha256"]
    assert set(first["paired"]) == set(first["held_out"]["per_class"])
    for cls, paired in first["paired"].items():
        both = [(c, b) for c, b in zip(first["held_out"]["per_frame"][cls], baseline["held_out"]["per_frame"][cls],
                                       strict=True) if c is not None and b is not None]
        assert paired["n"] == len(both) and paired["wins"] == sum(c > b for c, b in both)

    second = run_campaign_step(spec, 0.1, eval_seed=12, cache_dir=cache, keep=True, log=lambda m: None)
    assert second["start"] == "resumed" and second["steps_before"] == first["steps_after"]
    assert second["steps_after"] > second["steps_before"] and second["frames_rendered"] == 0  # the bank is reused
    restart, manifest = load_checkpoint(spec.restart_weights)
    assert {str(t.dtype) for t in restart.values() if t.is_floating_point()} == {"torch.float16"}
    assert manifest["sha256"] == second["kept_as_restart"]

    # the kept weights measured again beside the baseline, on the frames of the run that kept them
    again = compare_restart_weights(spec, cache_dir=cache)
    assert (again["run"], again["seed"], again["frames"]) == (2, 12, 2)
    for cls in again["paired"]:
        np.testing.assert_array_equal(_floats(again["baseline"]["per_frame"][cls]),
                                      _floats(second["baseline"]["held_out"]["per_frame"][cls]))
    with pytest.raises(ValueError, match="run or eval_seed, not both"):
        compare_restart_weights(spec, run=1, eval_seed=3, cache_dir=cache)
    with pytest.raises(ValueError, match="ledger's runs 1..2, got 9"):
        compare_restart_weights(spec, run=9, cache_dir=cache)
    assert main(["campaign", "compare", "tiny", "--run", "1", "--campaigns-dir", str(campaigns), "--cache",
                 str(cache), "-q"]) == 0

    # another machine: no run in its cache, the committed weights in the repository
    other = tmp_path / "other-cache"
    third = run_campaign_step(spec, 0.1, eval_seed=13, cache_dir=other, log=lambda m: None)
    assert (third["start"], third["steps_before"]) == ("restart from committed weights", 0)
    _, widened = load_checkpoint(campaign_run_dir(spec, other).parent / "restart-float32.safetensors")
    assert third["init_weights"] == widened["sha256"] and widened["rounded_to"] == "float16"

    runs = read_ledger(spec.ledger_path)
    assert [r["run"] for r in runs] == [1, 2, 3]
    table = ledger_table(runs)
    assert np.allclose(table["cpu_h_total"], np.cumsum([r["cpu_hours"] for r in runs]))
    assert list(table["held_out_seed"]) == [11, 12, 13]
    assert list(table["baseline_screws_iou"]) == [r["baseline"]["held_out"]["per_class"]["screws"]["iou"]
                                                  for r in runs]


def test_the_cli_prints_the_ledger_and_refuses_what_is_wrong(tmp_path, capsys):
    campaigns = _campaign(tmp_path / "campaigns")
    assert main(["campaign", "ledger", "tiny", "--campaigns-dir", str(campaigns)]) == 0
    assert "no run yet" in capsys.readouterr().out
    assert main(["campaign", "run", "nope", "--minutes", "1", "--campaigns-dir", str(campaigns)]) == 2
    assert "campaigns here: ['tiny']" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["campaign", "run", "tiny", "--minutes", "0", "--campaigns-dir", str(campaigns)])
    assert "minutes must be a finite number > 0, got '0'" in capsys.readouterr().err


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("seed = 7", "seed = 7\nbudget = 3"), "unknown: \\['budget'\\]"),
    (lambda t: t.replace('task = "segmentation"', 'task = "tracking"'), "task must be 'segmentation' or"),
    (lambda t: t.replace("patience = 50", "patience = 50\nmax_minutes = 5"), "max_minutes is set by each step"),
    (lambda t: t.replace("n_val = 2", "n_val = 0"), "\\[training\\]: n_val"),
    (lambda t: t.replace("frames = 2", "frames = 0"), "\\[evaluation\\] frames"),
    (lambda t: t.replace("[evaluation]", "[evaluation]\nworkers = 2"), "\\[evaluation\\] has keys"),
    (lambda t: t.replace("[evaluation]", "[evaluation]\nbaseline = 3"), "baseline must be a .safetensors path"),
    (lambda t: t.replace("[evaluation]", '[evaluation]\nbaseline = "data/models/none.safetensors"'),
     "baseline .*none.safetensors' does not exist"),
])
def test_a_wrong_definition_is_refused_naming_the_file_and_the_key(tmp_path, edit, message):
    campaigns = _campaign(tmp_path / "campaigns", edit(TINY))
    with pytest.raises(ValueError, match=message):
        load_campaign("tiny", campaigns)


def test_the_baseline_is_the_shipped_network_unless_the_definition_names_one_or_none(tmp_path):
    campaigns = tmp_path / "campaigns"
    assert load_campaign("tiny", _campaign(campaigns)).baseline == MODELS_DIR / "unet_standard.safetensors"
    _campaign(campaigns, TINY.replace("[evaluation]", "[evaluation]\nbaseline = false"), name="alone")
    assert load_campaign("alone", campaigns).baseline is None
    named = '[evaluation]\nbaseline = "data/models/unet_tracking.safetensors"'
    _campaign(campaigns, TINY.replace("[evaluation]", named), name="other")
    assert load_campaign("other", campaigns).baseline.name == "unet_tracking.safetensors"


def test_held_out_results_of_other_frames_are_not_compared():
    from histostudy.study.campaign import compare_held_out

    result = {"seed": 1, "frames": 2, "render_key": "k", "per_frame": {"direction_error_deg": [3.0, 4.0]}}
    with pytest.raises(ValueError, match="other frames: seed 1 and 2"):
        compare_held_out("orientation", result, {**result, "seed": 2})
    with pytest.raises(ValueError, match="task must be"):
        compare_held_out("tracking", result, result)
    paired = compare_held_out("orientation", result, {**result, "per_frame": {"direction_error_deg": [5.0, 3.0]}})
    assert (paired["direction_error_deg"]["wins"], paired["direction_error_deg"]["losses"]) == (1, 1)


def test_wrong_arguments_are_refused_before_anything_runs(tmp_path):
    campaigns = _campaign(tmp_path / "campaigns")
    with pytest.raises(ValueError, match="name must be a campaign's folder name"):
        load_campaign("../tiny", campaigns)
    spec = load_campaign("tiny", campaigns)
    for kwargs, message in [({"minutes": 0.0}, "minutes"), ({"eval_seed": -1}, "eval_seed"),
                            ({"eval_frames": 0}, "eval_frames"), ({"render_workers": 0}, "render_workers")]:
        args = {"minutes": 1.0, "eval_seed": 1, "cache_dir": tmp_path / "cache", **kwargs}
        with pytest.raises(ValueError, match=message):
            run_campaign_step(spec, args.pop("minutes"), **args)
    assert not (tmp_path / "cache").exists() and not spec.ledger_path.exists()


def test_a_second_step_on_the_same_machine_is_refused_while_one_runs(tmp_path):
    import fcntl

    spec = load_campaign("tiny", _campaign(tmp_path / "campaigns"))
    lock_path = campaign_run_dir(spec, tmp_path / "cache").parent / "lock"
    lock_path.parent.mkdir(parents=True)
    with open(lock_path, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        with pytest.raises(BlockingIOError, match="another step is running"):
            run_campaign_step(spec, 1.0, eval_seed=1, cache_dir=tmp_path / "cache")
    assert json.loads(json.dumps(read_ledger(spec.ledger_path))) == []


def test_the_committed_campaigns_load_and_pair_their_widths():
    from histostudy.study.campaign import CAMPAIGNS_DIR

    specs = [load_campaign(p.parent.name) for p in sorted(CAMPAIGNS_DIR.glob("*/campaign.toml"))]
    assert {s.name for s in specs} >= {"unet-w8", "unet-w16", "vgg19-w125", "vgg19-w25"}
    for spec in specs:
        assert spec.description and spec.training.render.splat_device == "cpu"  # the bank: compiled frames
        if spec.training.init_weights:
            assert Path(spec.training.init_weights).is_file(), spec.name
    # two widths of each network on one bank of frames (issue 55: accuracy against CPU-hours per width)
    by_name = {s.name: s.training for s in specs}
    for narrow, wide in (("unet-w8", "unet-w16"), ("vgg19-w125", "vgg19-w25")):
        assert by_name[narrow].render == by_name[wide].render and by_name[narrow].n_train == by_name[wide].n_train


def test_a_run_started_from_another_definition_is_not_resumed(tmp_path):
    spec = load_campaign("tiny", _campaign(tmp_path / "campaigns"))
    run_dir = campaign_run_dir(spec, tmp_path / "cache")
    run_dir.mkdir(parents=True)
    # what a run of the definition before an edit left: its configuration had 9 training frames
    (run_dir / "state.json").write_text(json.dumps({"config": {"task": "segmentation", "n_train": 9}, "seed": 7,
                                                    "profile": "campaign tiny", "state": {"elapsed_s": 0.0,
                                                                                          "steps": 0}}))
    with pytest.raises(ValueError, match="its definition .* changed since the run in .* started"):
        run_campaign_step(spec, 1.0, eval_seed=1, cache_dir=tmp_path / "cache", log=lambda m: None)
    assert not spec.ledger_path.exists()
