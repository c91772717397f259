"""Deprecated path: ``histostudy.orientation`` moved to :mod:`histostudy.learning` (docs/architecture.md, "Where modules moved").

Kept so that existing scripts still import; it re-exports the old module's public names and warns.
"""

import warnings

from histostudy.learning import (LearnedOrientation, N_ORIENTATION_CLASSES, OracleOrientation,
                                 OrientationSource, angles_from_direction, beam_direction_of_pose,
                                 default_vgg19, direction_candidates, hemisphere_angles,
                                 hemisphere_directions, orientation_angle_error, orientation_class,
                                 select_direction, wrap_angle)
from histostudy.pose import default_orientation

__all__ = ["LearnedOrientation", "N_ORIENTATION_CLASSES", "OracleOrientation", "OrientationSource", "angles_from_direction", "beam_direction_of_pose", "default_orientation", "default_vgg19", "direction_candidates", "hemisphere_angles", "hemisphere_directions", "orientation_angle_error", "orientation_class", "select_direction", "wrap_angle"]

warnings.warn("histostudy.orientation is deprecated: import from histostudy.learning instead", DeprecationWarning, stacklevel=2)
