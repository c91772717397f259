"""The pose-estimation cost of §II-B.3 (eq. 3): :class:`PoseCost` (``_model``), the fused numba
kernels it runs on (``_kernels``) and the plain numpy reference the tests compare them with
(``_reference``). Distances in pixels of each view's detector, model points in mm in the transducer
frame, poses 4x4 ``T_carm_transducer`` (docs/architecture.md, "Frames and units").
"""

from . import _kernels, _model, _reference
from ._model import OUTSIDE_DISTANCE_PX, PARALLEL_MIN_PROJECTIONS, PoseCost

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_model.__all__, *_kernels.__all__, *_reference.__all__]))
