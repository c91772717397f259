"""Tests of histostudy.study.pose._section: notebook 04's section written end to end on a tiny profile
(one experiment, the fast mode, oracle stages), and what it records against the study's own numbers."""

import json

import numpy as np
import pytest

from histostudy.reporting import PAPER, SectionWriter
from histostudy.study import pose as study
from histostudy.study.pose.metrics import mean_sd, table2

TINY = dict(photons_per_pixel=5e4, n_splats=2, splat_sigma_mm=0.5, pose_spacing_mm=0.47, render_spacing_mm=0.47,
            splat_device="cpu",
            background="phantom", n_experiments=1, margin_mm=[10.0], modes=["fast"], distance_maps=["occlusion_aware"],
            degradation="table1", robustness_poses=1, degradation_levels=[0.0], degradation_poses=1,
            learned_stages=False, learned_experiments=1, noise_photons=[5e4], noise_poses=1, cbct_reference=True,
            phantom_voxel_mm=0.75, cbct_voxel_mm=1.0, robustness_vgg19=False, independent_projector=False,
            projector_study_poses=0, projector_random_poses=0)


def test_parameters_make_the_study_config_and_refuse_unknown_names():
    params = study.PoseSectionConfig(**TINY)
    config = params.study_config()
    assert config.margin_mm == (10.0,) and config.modes == ("fast",) and config.n_splats == 2
    assert config.distance_maps == ("occlusion_aware",) and config.track  # the config's own default
    assert params.recorded() == TINY  # the report records the parameters as given
    assert study.PoseSectionConfig.from_parameters({**TINY, "seed": 3}) == params
    with pytest.raises(TypeError, match="n_poses"):
        study.PoseSectionConfig(**TINY, n_poses=3)
    with pytest.raises(ValueError, match="notebook 04"):
        study.PoseSectionConfig.from_parameters({k: v for k, v in TINY.items() if k != "noise_poses"})


@pytest.mark.slow
def test_the_section_records_the_studys_own_numbers(tmp_path):
    writer = SectionWriter(tmp_path, "04_pose_estimation", "04", profile="test", seed=5, parameters=TINY)
    setup = study.prepare(TINY, 5, timer=writer.timer)
    assert not setup.stages.learned and (setup.table_mode, setup.main_maps) == ("fast", "occlusion_aware")
    run = study.experiments_part(setup, timer=writer.timer)
    assert len(run.records) == 7 + 6 and run.failed.empty  # centre, six margins, six tracked
    reference = study.cbct_reference_part(setup, run, timer=writer.timer)
    assert reference.metrics is not None and reference.errors is not None
    shown = study.table2_part(setup, run, reference, paper=PAPER)
    assert list(shown.table.columns)[:3] == ["", "Depth: CBCT / truth", "Depth (paper)"]
    overlay = study.pose_overlay(setup)
    assert len(overlay.frames) == 2 and overlay.caption.startswith("Fig. 6") and overlay.focal_error_mm < 2.0
    learned, projector = study.learned_stages_part(setup, run), study.projector_part(setup)
    assert learned.table is None and projector.table is None
    study.record(writer, run, reference, shown, study.variants_part(setup, run),
                 study.robustness_part(setup, timer=writer.timer), study.degradation_part(setup, timer=writer.timer),
                 learned, projector, study.closing_part(setup, run))
    result = json.loads(writer.save().read_text())

    _, values = table2(reference.metrics, "fast", "occlusion_aware")
    _, truth = table2(run.metrics, "fast", "occlusion_aware")
    compared = {c["key"]: c for c in result["comparisons"]}
    assert compared["table2.center_mae.overall"]["ours"] == pytest.approx(values["table2.center_mae.overall"][0])
    assert compared["table2_truth.radius_mae.depth"]["ours"] == pytest.approx(truth["table2.radius_mae.depth"][0])
    assert compared["pose.cbct_reference_error_mm"]["ours"] == pytest.approx(
        mean_sd(reference.reference["ref_err_euclidean"])[0])
    assert compared["pose.n_studies"]["ours"] == 1 and "pose.init_success.robust" in compared
    assert result["values"]["table2_reference"] == "cbct" and result["values"]["failed_estimates"] == []
    assert [t["name"] for t in result["tables"]] == [
        "pose_records", "experiment_metrics", "cbct_reference", "experiment_metrics_cbct", "cbct_reference_error",
        "table2", "table2_truth", "variants", "stage_timing", "robustness", "robustness_summary", "degradation"]
    assert list(result["timings_s"])[:4] == ["build models", "pose study", "CBCT reference", "robustness sweep"]
    assert any("learned stages were not run: disabled" in t for t in result["text"])
    assert any(s["lab"].startswith("U-Net") for s in result["stand_ins"])
    focal_shift = np.linalg.norm(setup.physical.focal_point_mm)
    assert f"{focal_shift:.2f} mm (manufacturing deviation)" in result["text"][-1]
