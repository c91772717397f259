"""histostudy: the X-ray C-arm guided automatic targeting system for histotripsy of Wagner et al.
(IEEE TBME 2023), rebuilt in Python and reproduced on synthetic data.

One subpackage per concern, lowest layer first (docs/architecture.md, "Layers"; each imports only
from the layers below it): ``core`` (file writes, seeding, provenance), ``geometry`` (rigid
transforms), ``transducer`` (§II-B.1), ``imaging`` (views eq. 1-2, frames, rendering, scenes,
CBCT, §II-A, §II-B.2), ``learning`` (U-Net and VGG19, §II-B.2, §II-B.4), ``pose`` (eq. 3-5,
§II-B.3-4), ``calibration`` and ``robot`` (§II-C), ``treatment`` (§II-D, §II-E.3-4), ``study``
(one front module or sub-package per notebook) and ``reporting`` (profiles, the papermill
pipeline, the report beside the paper's values), and ``cli``, the ``histostudy`` command.
"""

__version__ = "0.2.0"
