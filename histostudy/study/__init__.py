"""The study: one folder per notebook, each returning pandas tables, figures and plain values (it never
prints). Each folder's ``__init__`` gives the notebook's ``<Section>Config``, its ``prepare``, the part
functions returning :class:`~.section.SectionPart` objects and :func:`~.section.record`; a notebook
imports its folder (``from histostudy.study import segmentation as study``). Shared by several:
:mod:`.section` (the section interface), :mod:`.stats` (metrics and tests, §II-E.1-2) and
:mod:`.held_out` (notebooks 02 and 03's parameters, held-out frames and checkpoints).

- :mod:`.projections` — notebook 01: the digital and physical models, a biplane pair, render timing
  (§II-A eq. 1-2, §II-B.1, §II-B.2).
- :mod:`.segmentation` — notebook 02: the U-Net, Table I, ANOVA and Tukey HSD (§II-B.2, §II-E.1, §III).
- :mod:`.orientation` — notebook 03: the VGG19's azimuth and elevation, the conic initialiser beside
  it (§II-B.4 eq. 4, §II-E.2, §III).

Notebook 04, the pose-estimation experiments and Table II (§II-B.3, §II-B.4, §II-D, §II-E.3,
§III): the sub-package :mod:`.pose` — its configuration and the stages it runs on, error
directions and poses, the experiments, the CBCT reference, Table II and the other summaries,
initialisation over random poses, the sweeps, RTK's projector beside ours, and the report section.

Notebook 05, calibration, targeting and treatment of the phantom (§II-C, §II-D, §II-E.4, §III,
Fig. 7): the sub-package :mod:`.targeting` — the set-up and ground truth, the robots, the hand-eye
calibration, positioning, treatment, one experiment and the study, §III's summaries, Fig. 7's
figures, and the notebook's parameters and set-up.

- :mod:`.your_data` — notebook 06: the lab's own data end to end (§II-B to §II-D on a lab's files),
  with its helpers ``lab_dataset``, ``moving_cine`` and ``moving_cine_live``.

Notebook 07, the error budget (§III, §IV): the sub-package :mod:`.budget` — the lab's error
sources (:class:`LabErrorModel`), the runs under every configuration, the summaries and the
notebook's parameters.

``histostudy.study.LabErrorModel`` is the one name this package gives itself, imported on first
use so that importing a notebook's module costs no more than that module.
"""

__all__ = ["LabErrorModel"]


def __getattr__(name: str):
    if name == "LabErrorModel":
        from .budget import LabErrorModel

        return LabErrorModel
    raise AttributeError(f"module 'histostudy.study' has no attribute {name!r}")
