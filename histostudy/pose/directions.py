"""The orientation stage of :func:`~histostudy.pose.estimate_pose` (§II-B.4, eq. 4): each view's two
candidate focal directions (unit vectors in the C-arm frame), read through a direction stage
``(view_index, labels, maps, rng) -> (2, 3)``; :class:`SourceDirections` is the stage of an
orientation source over the frames.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from histostudy.imaging import Frame
from histostudy.learning import direction_candidates

from .distance_maps import DistanceMaps

__all__ = ["DirectionStage", "SourceDirections", "check_direction_pair", "unit_direction_pair"]

#: ``(view_index, labels, maps, rng) -> (2, 3)`` unit world focal-direction candidates of one view.
DirectionStage = Callable[[int, np.ndarray, DistanceMaps, np.random.Generator], np.ndarray]


def check_direction_pair(pair, who: str) -> np.ndarray:
    """``pair`` as a float64 ``(2, 3)`` array of finite directions; ValueError naming ``who`` otherwise."""
    pair = np.asarray(pair, dtype=np.float64)
    if pair.shape != (2, 3) or not np.all(np.isfinite(pair)):
        raise ValueError(f"{who} returned shape {pair.shape}; expected two finite world directions (2, 3)")
    return pair


def unit_direction_pair(pair, who: str) -> np.ndarray:
    """:func:`check_direction_pair`, each direction then divided by its length."""
    pair = check_direction_pair(pair, who)
    return pair / np.linalg.norm(pair, axis=1, keepdims=True)


class SourceDirections:
    """The direction stage (§II-B.4, eq. 4) of an orientation source over ``frames``.

    Called as ``stage(view_index, labels, maps, rng)``, it returns that view's two candidate focal
    directions, ``(2, 3)`` unit vectors in the C-arm frame from the transducer centre to the focal
    point. A source with a ``direction_candidates_from_labels(frame, labels, rng, maps=)`` method
    (the geometric :class:`~histostudy.pose.conic_orientation.ConicOrientation`) reads the labels and
    distance maps already made (no second segmentation); any other source gives eq. 4's mirror pair
    of its ``estimate(frame, rng) -> (azimuth, elevation)`` (rad).

    Args:
        orientation: the orientation source (an :class:`~histostudy.learning.OrientationSource`).
        frames: the frames the labels came from, one per view, in the views' order.

    Raises:
        ValueError: (when called) the source's pair is not two finite directions.
    """

    def __init__(self, orientation, frames: Sequence[Frame]):
        self.orientation, self.frames = orientation, list(frames)

    def __call__(self, index: int, labels: np.ndarray, maps: DistanceMaps, rng: np.random.Generator) -> np.ndarray:
        frame = self.frames[index]
        from_labels = getattr(self.orientation, "direction_candidates_from_labels", None)
        if from_labels is not None:
            return unit_direction_pair(from_labels(frame, labels, rng, maps=maps),
                                       f"{type(self.orientation).__name__}.direction_candidates_from_labels")
        azimuth_rad, elevation_rad = self.orientation.estimate(frame, rng)
        return direction_candidates(azimuth_rad, elevation_rad, frame.view)
