"""The study: one module (or one front module over a few) per notebook and paper result; each
returns pandas tables and plain values and never prints.

Each notebook's section has one interface (:mod:`.section`): a ``<Section>Config`` of the notebook's
parameters, checked; a ``prepare`` that makes its ``<Section>Setup``; functions returning tables
and figures as :class:`~.section.SectionPart` objects that :func:`~.section.record` writes through
the ``SectionWriter`` a notebook passes in; this layer sits below ``reporting`` and does not import
it. Nothing is imported here: a notebook imports its module
(``from histostudy.study import segmentation as study``).

Notebook 01, 02, 03:

- :mod:`.transducer_projections` — notebook 01: the digital and physical models, a synthetic
  biplane pair, render timing (§II-A eq. 1-2, §II-B.1, §II-B.2).
- :mod:`.segmentation` — notebook 02: the U-Net on held-out hybrid frames, Table I, ANOVA and
  Tukey HSD (§II-B.2, §II-E.1, §III).
- :mod:`.held_out` — notebooks 02 and 03: the parameters they share, the held-out hybrid frames
  and the shipped checkpoints they evaluate.
- :mod:`.orientation_regression` — notebook 03: VGG19 azimuth and elevation against the true
  pose, MAE, Pearson, Moore-Penrose fit; the conic initialiser beside it (§II-B.4 eq. 4, §II-E.2,
  §III).
- :mod:`.section` — every notebook: the section interface (parameters checked by name, the
  parts of a section and :func:`~.section.record`).
- :mod:`.stats` — notebooks 02 and 03: segmentation metrics, one-way ANOVA, Tukey HSD, angle
  statistics (§II-E.1, §II-E.2).

Notebook 04, the pose-estimation experiments and Table II (§II-B.3, §II-B.4, §II-D, §II-E.3,
§III): the sub-package :mod:`.pose` — its configuration and the stages it runs on, error
directions and poses, the experiments, the CBCT reference, Table II and the other summaries,
initialisation over random poses, the sweeps, RTK's projector beside ours, and the report section.

Notebook 05, calibration, targeting and treatment of the phantom (§II-C, §II-D, §II-E.4, §III,
Fig. 7): the sub-package :mod:`.targeting` — the set-up and ground truth, the robots, the hand-eye
calibration, positioning, treatment, one experiment and the study, §III's summaries, Fig. 7's
figures, and the notebook's parameters and set-up.

Notebook 06, the lab's own data end to end (§II-B to §II-D on a lab's files):

- :mod:`.your_data` — the notebook's parameters, inputs, the poses of the stations and the cine,
  the calibration and the planned (or executed) move, each as a table, and the cine streamed over
  DICOM to the receiver on loopback.
- :mod:`.lab_dataset` — the lab-like dataset it generates when no lab files are given (DICOM XA,
  NIfTI CBCT, STL meshes, flange poses, and the synthetic truth beside them).
- :mod:`.moving_cine` — a biplane cine of the robot carrying the transducer between the study's
  margin points, as timed DICOM XA frames, the truth apart.
- :mod:`.moving_cine_live` — that cine streamed at its frame rate through the receiver: a row per
  frame (posed, dropped, refused; focal error; latency), the counts and the figure.

Notebook 07, the error budget (§III, §IV): the sub-package :mod:`.budget` — the lab's error
sources (:class:`LabErrorModel`), the runs under every configuration, the summaries and the
notebook's parameters.

``histostudy.study.LabErrorModel`` is the one name this package gives itself, imported on first
use so that importing a notebook's module costs no more than that module.
"""

__all__ = ["LabErrorModel"]


def __getattr__(name: str):
    if name == "LabErrorModel":
        from .budget._sources import LabErrorModel

        return LabErrorModel
    raise AttributeError(f"module 'histostudy.study' has no attribute {name!r}")
