"""Tests of histostudy.study.pose._config: the study's parameters and the stages it runs on."""

import pytest

from histostudy.study.pose.experiments import PoseStudyConfig, study_stages


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="n_experiments"):
        PoseStudyConfig(n_experiments=0)
    with pytest.raises(ValueError, match="margin_mm"):
        PoseStudyConfig(margin_mm=(10.0, -1.0))
    with pytest.raises(ValueError, match="modes"):
        PoseStudyConfig(modes=("gradient",))
    with pytest.raises(ValueError, match="distance_maps"):
        PoseStudyConfig(distance_maps=("chamfer",))
    with pytest.raises(ValueError, match="degradation must be one of"):
        PoseStudyConfig(degradation="unet")
    assert PoseStudyConfig(modes=("paper", "fast"), distance_maps=("occlusion_aware", "per_class")).variants == [
        ("paper", "occlusion_aware"), ("paper", "per_class"), ("fast", "occlusion_aware"), ("fast", "per_class")]


def test_study_stages_are_learned_when_they_meet_the_requirements_else_the_oracles():
    import types

    from histostudy.learning import OracleOrientation, OracleSegmenter

    config = PoseStudyConfig(n_experiments=1)
    good_seg = types.SimpleNamespace(manifest={"validation": {"pixel_accuracy": 0.97}, "weights_file": "u.safetensors"})
    good_vgg = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 3.0, "elevation_mae_deg": 2.0},
                                               "weights_file": "v.safetensors"})
    poor_vgg = types.SimpleNamespace(manifest={"validation": {"azimuth_mae_deg": 45.3, "elevation_mae_deg": 15.7}})
    stages = study_stages(config, segmenter=good_seg, orientation=good_vgg)
    assert stages.learned and (stages.segmenter, stages.orientation) == (good_seg, good_vgg)
    assert "u.safetensors" in stages.why and "v.safetensors" in stages.why
    stages = study_stages(config, segmenter=good_seg, orientation=poor_vgg)
    assert not stages.learned and "45.3 deg exceeds 30.0" in stages.why
    assert isinstance(stages.segmenter, OracleSegmenter) and isinstance(stages.orientation, OracleOrientation)
    assert (stages.shipped_segmenter, stages.shipped_orientation) == (good_seg, poor_vgg)  # for the comparison
    assert stages.segmenter.degradation is not None  # the config's Table I oracle, not perfect labels
    stages = study_stages(config, learned=False, segmenter=good_seg, orientation=good_vgg)
    assert not stages.learned and "disabled" in stages.why
    assert stages.shipped_segmenter is None and stages.shipped_orientation is None


def test_the_config_renders_with_the_shared_render_settings():
    from histostudy.imaging import FrameRenderConfig
    from histostudy.study.pose.experiments import PoseStudyConfig

    config = PoseStudyConfig(photons_per_pixel=1e4, n_splats=8)
    assert isinstance(config, FrameRenderConfig) and config.background == "phantom"  # §II-D: agarose phantoms
    assert config.frame_kwargs() == {"photons_per_pixel": 1e4, "n_splats": 8, "splat_sigma_mm": 0.5, "device": None}
    assert PoseStudyConfig(splat_device="cpu").frame_kwargs()["device"] == "cpu"
    with pytest.raises(ValueError, match="n_splats"):
        PoseStudyConfig(n_splats=0)
    with pytest.raises(ValueError, match="background must be one of"):
        PoseStudyConfig(background="water")
