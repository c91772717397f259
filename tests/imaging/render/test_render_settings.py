"""Tests of histostudy.imaging.render._settings: the one declaration of the rendering settings."""

import inspect

import numpy as np
import pytest

from histostudy.imaging import FrameRenderConfig, default_biplane, render_frame
from histostudy.transducer import TransducerModel, pose_facing


def test_defaults_are_render_frames_and_the_papers():
    defaults = {k: p.default for k, p in inspect.signature(render_frame).parameters.items()}
    for name, value in FrameRenderConfig().frame_kwargs().items():
        assert defaults[name] == value, name
    assert FrameRenderConfig() == FrameRenderConfig(5e4, 16, 0.5, "phantom")  # §II-B.2: 16 splats, 0.5 mm


def test_frame_kwargs_render_the_same_frame_as_the_explicit_arguments():
    model = TransducerModel.build(spacing_mm=0.94)
    view = default_biplane()[0]
    settings = FrameRenderConfig(photons_per_pixel=2e4, n_splats=3, splat_sigma_mm=0.3, background="none")
    via_settings = render_frame(model, pose_facing(), view, rng=np.random.default_rng(4), **settings.frame_kwargs())
    explicit = render_frame(model, pose_facing(), view, rng=np.random.default_rng(4), photons_per_pixel=2e4,
                            n_splats=3, splat_sigma_mm=0.3)
    np.testing.assert_array_equal(via_settings.image, explicit.image)
    noiseless = render_frame(model, pose_facing(), view, rng=np.random.default_rng(4),
                             **FrameRenderConfig(photons_per_pixel=None, n_splats=3, splat_sigma_mm=0.3).frame_kwargs())
    assert not np.array_equal(noiseless.image, explicit.image)


@pytest.mark.parametrize("field, value", [("photons_per_pixel", 0.0), ("photons_per_pixel", float("nan")),
                                          ("photons_per_pixel", True), ("n_splats", 0), ("n_splats", 2.5),
                                          ("splat_sigma_mm", -0.1), ("splat_sigma_mm", float("inf")),
                                          ("background", "water")])
def test_bad_settings_name_the_field_and_value(field, value):
    with pytest.raises(ValueError, match=field if field != "background" else "background must be one of"):
        FrameRenderConfig(**{field: value})


def test_settings_are_frozen_and_hashable():
    settings = FrameRenderConfig()
    with pytest.raises(AttributeError):
        settings.n_splats = 4
    assert len({settings, FrameRenderConfig()}) == 1
