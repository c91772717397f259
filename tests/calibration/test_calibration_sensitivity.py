"""Tests of histostudy.calibration.sensitivity: the Monte-Carlo of the calibration error (beyond the paper)."""

import numpy as np
import pandas as pd
import pytest

from histostudy import calibration as he


def test_calibration_sensitivity_shapes_determinism_and_trends():
    kw = dict(n_poses_list=(4, 12), noise_levels=((0.0, 0.0), (0.5, 0.2)), n_trials=25)
    df = he.calibration_sensitivity(rng=1, **kw)
    assert isinstance(df, pd.DataFrame) and len(df) == 2 * 2 * 25
    for col in ("X_rotation_error_deg", "X_translation_error_mm", "Y_rotation_error_deg",
                "Y_translation_error_mm", "target_error_mm"):
        assert col in df and np.all(np.isfinite(df[col]))
    exact = df[df.noise_translation_mm == 0.0]
    assert exact[["X_translation_error_mm", "Y_translation_error_mm", "target_error_mm"]].to_numpy().max() < 1e-8
    noisy = df[df.noise_translation_mm == 0.5].groupby("n_poses")
    mean_err = noisy["X_translation_error_mm"].mean()
    assert mean_err[4] > 0.1 and mean_err[12] < mean_err[4]  # more poses, smaller error
    assert noisy["target_error_mm"].mean()[12] < noisy["target_error_mm"].mean()[4]
    pd.testing.assert_frame_equal(df, he.calibration_sensitivity(rng=np.random.default_rng(1), **kw))
    with pytest.raises(ValueError, match="n_poses_list"):
        he.calibration_sensitivity(n_poses_list=(2,), rng=0)
    with pytest.raises(TypeError, match="rng"):
        he.calibration_sensitivity(rng=None)


def test_calibration_sensitivity_gives_the_same_rows_in_process_or_on_a_local_cluster(monkeypatch):
    kw = dict(n_poses_list=(4, 8), noise_levels=((0.5, 0.2), (1.0, 0.4)), n_trials=6, rng=3)
    monkeypatch.delenv("HISTOSTUDY_SCHEDULER", raising=False)
    sequential = he.calibration_sensitivity(**kw)  # the default: this process
    cluster = he.calibration_sensitivity(**kw, executor="local:2")
    pd.testing.assert_frame_equal(sequential, cluster, check_exact=True)
    assert len(sequential) == 2 * 2 * 6 and list(sequential["trial"][:2]) == [0, 0]
    monkeypatch.setenv("HISTOSTUDY_SCHEDULER", "local:0")  # the default executor comes from the environment
    with pytest.raises(ValueError, match="HISTOSTUDY_SCHEDULER: the workers of 'local:<workers>'"):
        he.calibration_sensitivity(**kw)
