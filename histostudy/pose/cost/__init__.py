"""The pose-estimation cost of §II-B.3 (eq. 3): :class:`PoseCost`, on fused numba kernels
(``_kernels``) checked against a plain numpy reference (``_reference``). Distances in pixels of
each view's detector, model points in mm in the transducer frame, poses 4x4 T_carm_transducer.
"""

from ._model import OUTSIDE_DISTANCE_PX, PoseCost

__all__ = ["PoseCost", "OUTSIDE_DISTANCE_PX"]
