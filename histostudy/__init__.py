"""histostudy: the X-ray C-arm guided automatic targeting system for histotripsy of Wagner et al.
(IEEE TBME 2023), rebuilt in Python and reproduced on synthetic data.

Modules (see docs/architecture.md, Data flow): ``geometry`` (rotations, transforms), ``carm``
(views, eq. 1-2), ``transducer`` (digital and physical model, §II-B.1), ``render`` and ``anatomy``
(synthetic fluoroscopy, §II-B.2), ``frame`` (images with their geometry), ``profiles``,
``pipeline`` and ``report`` (the papermill study and its report), ``paper`` (the paper's values).
"""

__version__ = "0.1.0"
