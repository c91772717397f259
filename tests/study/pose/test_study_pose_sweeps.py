"""Tests of histostudy.study.pose._sweeps: focal error vs dose and vs segmentation degradation."""

import numpy as np
import pytest

from histostudy.imaging import default_biplane
from histostudy.study.pose._sweeps import noise_sweep
from histostudy.study.pose.experiments import PoseStudyConfig
from histostudy.transducer import TransducerModel


@pytest.mark.slow
def test_noise_sweep_renders_each_dose_and_the_oracle_ignores_the_image():
    from histostudy.learning import OracleOrientation, OracleSegmenter

    model = TransducerModel.build(spacing_mm=0.47)
    physical = TransducerModel.build_physical(spacing_mm=0.47, rng=np.random.default_rng(3))
    config = PoseStudyConfig(n_splats=1)
    table = noise_sweep([2e3, 5e4], pose_model=model, render_model=model, physical=physical,
                              views=default_biplane(), seed=5, config=config, segmenter=OracleSegmenter(),
                              orientation=OracleOrientation(), n_poses=1)
    assert list(table["photons_per_pixel"]) == [2e3, 5e4] and table["ok"].all()
    # The oracle reads the labels, not the image: the same error at every dose.
    assert table["error_mm"].nunique() == 1 and table["error_mm"].iloc[0] < 1.0
    with pytest.raises(ValueError, match="photons_per_pixel"):
        noise_sweep([0.0], pose_model=model, render_model=model, physical=physical, views=default_biplane(),
                          seed=5, config=config, segmenter=OracleSegmenter())
