"""Tests of histostudy.learning.training._config: a run's configuration, its checks and the profiles' tables."""

import pytest

from histostudy.learning import RenderConfig, TrainingConfig
from histostudy.reporting import PROFILE_NAMES, load_profile

TINY = RenderConfig(render_spacing_mm=0.47, label_spacing_mm=0.47, detector=(240, 320))


def _seg(**kw):
    base = dict(task="segmentation", network={"arch": "unet", "base_width": 2, "depth": 2}, scale=0.5, crop=32,
                n_train=4, n_val=2, batch_size=2, max_epochs=2, render=TINY)
    return TrainingConfig(**{**base, **kw})


def test_config_validation_and_profiles():
    with pytest.raises(ValueError, match="task"):
        _seg(task="pose")
    with pytest.raises(ValueError, match="batch_size"):
        _seg(batch_size=9)
    with pytest.raises(ValueError, match="unknown keys"):
        TrainingConfig.from_table("segmentation", {"network": {"arch": "unet"}, "scale": 0.5, "epochs": 3})
    for name in PROFILE_NAMES:
        profile = load_profile(name)
        for task in ("segmentation", "orientation"):
            cfg = TrainingConfig.from_table(task, profile.training[task])
            assert cfg.batch_size == 5 or name == "smoke"
            assert cfg.learning_rate == 0.001
            if name == "paper":  # the paper's hyper-parameters; the others are CPU-sized (profile comments)
                assert (cfg.optimizer, cfg.momentum, cfg.patience) == ("sgd", 0.9, 3)
    paper = load_profile("paper").training["orientation"]
    assert TrainingConfig.from_table("orientation", paper).network["width"] == 1.0
