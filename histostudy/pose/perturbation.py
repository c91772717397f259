"""The pose parameterisation of the refinement (§II-B.3, beyond the paper's Nelder-Mead): the left
perturbation about the focal point and the Gauss-Newton normal equations taken with it.

The residual of point ``i`` in view ``a`` is ``r = sqrt(lambda_k / n_k) * d_a(u, v)`` (pixels), so
``sum r² = C`` of eq. 3. Its derivative is taken for a *left perturbation about the focal point*:
``p' = exp([w]x) (R p) + t + v`` (rotation about the current transducer origin, i.e. the focal
point, then translation; ``w`` in rad, ``v`` in mm, both in the C-arm frame), so
``dX/dw = -[R p]x`` and ``dX/dv = I``. :class:`~.cost.PoseCost` computes ``J = dr/d[w, v]``;
:mod:`.refine`'s Levenberg-Marquardt steps with :func:`apply_left_perturbation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from histostudy.geometry import matrix_from_rotvec

__all__ = ["NormalEquations", "apply_left_perturbation"]


@dataclass(frozen=True)
class NormalEquations:
    """Gauss-Newton quantities at one pose (left perturbation ``[w (rad), v (mm)]`` about the focal point).

    ``cost`` = C (eq. 3) = ``sum r²``; ``JtJ`` (6, 6) and ``Jtr`` (6,) with ``J = dr/d[w, v]``.
    The gradient of C is ``2 Jtr``.
    """

    cost: float
    JtJ: np.ndarray
    Jtr: np.ndarray


def apply_left_perturbation(T, delta) -> np.ndarray:
    """``T'`` with ``R' = exp([w]x) R`` and ``t' = t + v`` for ``delta = [w (rad), v (mm)]``.

    The rotation turns the transducer about its own origin (the focal point) in world axes, so
    rotation and translation steps do not mix; this is the perturbation the Jacobians of
    :class:`~.cost.PoseCost` are taken with.
    """
    T = np.asarray(T, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64).reshape(-1)
    if d.shape != (6,) or not np.all(np.isfinite(d)):
        raise ValueError(f"delta must be 6 finite numbers [w (rad), v (mm)], got {delta!r}")
    out = np.eye(4)
    out[:3, :3] = matrix_from_rotvec(d[:3]) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + d[3:]
    return out
