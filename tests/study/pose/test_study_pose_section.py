"""Tests of histostudy.study.pose._section: notebook 04's section written end to end on a tiny profile
(one experiment, the fast mode, oracle stages), and what it records against the study's own numbers."""

import json

import numpy as np
import pytest

from histostudy.reporting import PAPER, SectionWriter
from histostudy.study import pose as study

TINY = dict(photons_per_pixel=5e4, n_splats=2, splat_sigma_mm=0.5, pose_spacing_mm=0.47, render_spacing_mm=0.47,
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
    with pytest.raises(TypeError, match="n_poses"):
        study.PoseSectionConfig(**TINY, n_poses=3)


@pytest.mark.slow
def test_the_section_records_the_studys_own_numbers(tmp_path):
    writer = SectionWriter(tmp_path, "04_pose_estimation", "04", profile="test", seed=5, parameters=TINY)
    section = study.PoseSection(writer, study.PoseSectionConfig(**TINY), 5, paper=PAPER)
    assert not section.stages.learned and (section.table_mode, section.main_maps) == ("fast", "occlusion_aware")
    # out of the notebook's order: Table II first runs the experiments and the CBCT reference it reads
    shown = section.write_table2()
    assert len(section.records) == 7 + 6 and section.metrics_cbct is not None  # centre, six margins, six tracked
    records = section.records
    failed = section.run_experiments()  # already run: the same records, nothing written twice
    assert failed.empty and section.records is records and section.write_cbct_reference() is not None
    assert list(shown.columns)[:3] == ["", "Depth: CBCT / truth", "Depth (paper)"]
    section.write_variants()
    overlay = section.pose_overlay()
    assert len(overlay.frames) == 2 and overlay.caption.startswith("Fig. 6") and overlay.focal_error_mm < 2.0
    section.write_robustness()
    section.write_degradation()
    assert section.write_learned_stages() is None and section.write_projector_comparison() is None
    section.write_stand_ins()
    result = json.loads(writer.save().read_text())

    _, values = study.table2(section.metrics_cbct, "fast", "occlusion_aware")
    _, truth = study.table2(section.metrics, "fast", "occlusion_aware")
    compared = {c["key"]: c for c in result["comparisons"]}
    assert compared["table2.center_mae.overall"]["ours"] == pytest.approx(values["table2.center_mae.overall"][0])
    assert compared["table2_truth.radius_mae.depth"]["ours"] == pytest.approx(truth["table2.radius_mae.depth"][0])
    assert compared["pose.cbct_reference_error_mm"]["ours"] == pytest.approx(
        study.mean_sd(section.reference["ref_err_euclidean"])[0])
    assert compared["pose.n_studies"]["ours"] == 1 and "pose.init_success.robust" in compared
    assert result["values"]["table2_reference"] == "cbct" and result["values"]["failed_estimates"] == []
    assert [t["name"] for t in result["tables"]] == [
        "pose_records", "experiment_metrics", "cbct_reference", "experiment_metrics_cbct", "cbct_reference_error",
        "table2", "table2_truth", "variants", "stage_timing", "robustness", "robustness_summary", "degradation"]
    assert any("learned stages were not run: disabled" in t for t in result["text"])
    assert any(s["lab"].startswith("U-Net") for s in result["stand_ins"])
    focal_shift = np.linalg.norm(section.physical.focal_point_mm)
    assert f"{focal_shift:.2f} mm (manufacturing deviation)" in result["text"][-1]
