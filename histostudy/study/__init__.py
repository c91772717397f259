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
- :mod:`.pose` — notebook 04: the pose-estimation experiments and Table II (§II-B.3, §II-B.4, §II-D,
  §II-E.3, §III), the sweeps and RTK's projector beside ours; its experiment layer (the study's
  config and stages, the error directions, the metrics, the CBCT reference) is public for 05 and 07.
- :mod:`.targeting` — notebook 05: calibration, targeting and treatment of the phantom (§II-C,
  §II-D, §II-E.4, §III, Fig. 7); its experiment layer (set-up and ground truth, robots, one
  experiment and the study) is public for 06 and 07.
- :mod:`.your_data` — notebook 06: the lab's own data end to end (§II-B to §II-D on a lab's files),
  with its helpers ``lab_dataset``, ``moving_cine`` and ``moving_cine_live``.
- :mod:`.budget` — notebook 07: the error budget (§III, §IV), the lab's error sources
  (:class:`LabErrorModel`) drawn for one lab and many, the runs under every configuration and the
  shares of the error.

``histostudy.study.LabErrorModel`` is the one name this package gives itself, imported on first
use so that importing a notebook's module costs no more than that module.
"""

__all__ = ["LabErrorModel"]


def __getattr__(name: str):
    if name == "LabErrorModel":
        from .budget import LabErrorModel

        return LabErrorModel
    raise AttributeError(f"module 'histostudy.study' has no attribute {name!r}")
