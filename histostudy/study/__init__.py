"""The study: one module (or one front module over a few) per notebook and paper result; each
returns pandas tables and plain values and never prints.

Its ``record_*`` functions and section objects write a report section through the
``SectionWriter`` a notebook passes in; this layer sits below ``reporting`` and does not import
it. Nothing is imported here: a notebook imports its module
(``from histostudy.study import segmentation as study``).

Notebook 01, 02, 03:

- :mod:`.transducer_projections` — notebook 01: the digital and physical models, a synthetic
  biplane pair, render timing (§II-A eq. 1-2, §II-B.1, §II-B.2).
- :mod:`.segmentation` — notebook 02: the U-Net on held-out hybrid frames, Table I, ANOVA and
  Tukey HSD (§II-B.2, §II-E.1, §III); its shipped-weights and held-out-frame helpers serve
  notebook 03 too.
- :mod:`.orientation_regression` — notebook 03: VGG19 azimuth and elevation against the true
  pose, MAE, Pearson, Moore-Penrose fit; the conic initialiser beside it (§II-B.4 eq. 4, §II-E.2,
  §III).
- :mod:`.stats` — notebooks 02 and 03: segmentation metrics, one-way ANOVA, Tukey HSD, angle
  statistics (§II-E.1, §II-E.2).

Notebook 04, the pose-estimation experiments and Table II (§II-B.3, §II-B.4, §II-D, §II-E.3,
§III), gathered by the front module :mod:`.pose_estimation`:

- :mod:`.pose_config` — the study's configuration, the notebook's parameters and the stages it
  runs on (learned, or the oracles).
- :mod:`.pose_geometry` — error directions (depth, TB, LR), margin and random poses, the
  bubble-cloud centre, the rotation error modulo the half turn.
- :mod:`.pose_experiments` — Table II's experiments drawn, rendered and estimated.
- :mod:`.pose_reference` — the post-treatment CBCT reference of the focal point.
- :mod:`.pose_metrics` — Table II and the other summaries (mean ± SD, per variant, per stage).
- :mod:`.pose_robustness` — initialisation success over random poses, on spawned workers.
- :mod:`.pose_sweeps` — the focal error against segmentation degradation and against dose.
- :mod:`.pose_report_tables` — the report's tables and comparison rows.
- :mod:`.pose_section` — notebook 04's report section, part by part.
- :mod:`.projector_comparison` — beyond the paper: the pose pipeline on frames of RTK's
  independent projector (§II-B.2).

Notebook 05, calibration, targeting and treatment of the phantom (§II-C, §II-D, §II-E.4, §III,
Fig. 7), gathered by the front module :mod:`.targeting`:

- :mod:`.targeting_setup` — the study's configuration and the ground truth an experiment draws.
- :mod:`.targeting_robots` — the in-process ``SimulatedUR5e``, and the simulated controller
  driven through ``ur_rtde``.
- :mod:`.targeting_calibration` — the hand-eye calibration phase (§II-C).
- :mod:`.targeting_positioning` — the TCP on a CBCT target, and the true set-up there (§II-D).
- :mod:`.targeting_treatment` — treating a zone, and the bias-correcting calibration treatment
  (§II-D, §IV).
- :mod:`.targeting_experiment` — one targeting experiment and the study of several.
- :mod:`.targeting_summary` — §III's targeting figures, tables and comparisons with the paper.
- :mod:`.targeting_figures` — Fig. 7's cuts through the target, the 3-D scene's inputs.
- :mod:`.targeting_notebook` — notebook 05's parameters, set-up, seeds, stand-ins and text.

Notebook 06, the lab's own data end to end (§II-B to §II-D on a lab's files):

- :mod:`.your_data` — the notebook's inputs, the poses of the stations and the cine, the
  calibration and the planned move, each as a table.
- :mod:`.your_data_live` — the cine streamed over DICOM to the receiver on loopback, a live
  figure of the received poses, and the received poses beside the tracked ones.
- :mod:`.lab_dataset` — the lab-like dataset it generates when no lab files are given (DICOM XA,
  NIfTI CBCT, STL meshes, flange poses, and the synthetic truth beside them).
- :mod:`.moving_cine` — a biplane cine of the robot carrying the transducer between the study's
  margin points, as timed DICOM XA frames, the truth apart.
- :mod:`.moving_cine_live` — that cine streamed at its frame rate through the receiver: a row per
  frame (posed, dropped, refused; focal error; latency), the counts and the figure.

Notebook 07, the error budget (§III, §IV), gathered by the front module :mod:`.budget`:

- :mod:`.lab_errors` — :class:`LabErrorModel`: the lab's error sources, each documented and
  switchable, and one lab's draws of them.
- :mod:`.error_budget` — both studies run under every configuration (all on, each alone, all but
  one) on the same draws, on :func:`histostudy.core.run_sweep`.
- :mod:`.error_budget_summary` — the configurations' figures, the sources' shares, the waterfall
  and the comparisons with the paper.
- :mod:`.error_budget_notebook` — the notebook's parameters, set-up, seeds and prose.

``histostudy.study.LabErrorModel`` is the one name this package gives itself, imported on first
use so that importing a notebook's module costs no more than that module.
"""

__all__ = ["LabErrorModel"]


def __getattr__(name: str):
    if name == "LabErrorModel":
        from .budget._sources import LabErrorModel

        return LabErrorModel
    raise AttributeError(f"module 'histostudy.study' has no attribute {name!r}")
