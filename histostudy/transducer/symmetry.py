"""Whether a transducer model looks the same after a half turn about its axis (§II-B.4): the paper's axial
search covers [0, 180) deg only, which a lab's own transducer need not allow."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .digital import TransducerModel
from .spec import FEATURE_CLASSES

__all__ = ["HALF_TURN", "half_turn_symmetric"]

#: The half turn about the transducer's z axis (its beam axis), in the transducer frame.
HALF_TURN = np.diag([-1.0, -1.0, 1.0])


def half_turn_symmetric(model: TransducerModel, tolerance_mm: float | None = None) -> bool:
    """Whether a model looks the same after a half turn about its axis (z).

    Args:
        model: the transducer model.
        tolerance_mm: how far, in mm, a turned point may lie from a point of its class; None for half
            the model's grid spacing.

    Returns:
        True when every point of every feature class, turned by :data:`HALF_TURN`, lies within
        ``tolerance_mm`` of a point of the same class.

    Raises:
        TypeError: ``model`` is not a TransducerModel.
        ValueError: ``tolerance_mm`` is not a finite number > 0 or None.
    """
    if not isinstance(model, TransducerModel):
        raise TypeError(f"model must be a histostudy.transducer.TransducerModel, got {type(model).__name__}")
    tol = 0.5 * model.spacing_mm if tolerance_mm is None else tolerance_mm
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not np.isfinite(tol) or tol <= 0:
        raise ValueError(f"tolerance_mm must be a finite number > 0 (mm) or None, got {tolerance_mm!r}")
    for feature in FEATURE_CLASSES:
        points = np.asarray(model.points[feature], dtype=np.float64).reshape(-1, 3)
        if len(points) == 0:
            continue
        distance, _ = cKDTree(points).query(points @ HALF_TURN.T, distance_upper_bound=2 * tol)
        if not np.all(distance <= tol):
            return False
    return True
