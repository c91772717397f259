"""Rigid transforms and rotations: 4x4 homogeneous ``T_<to>_<from>`` in millimetres, rotations in
radians (``transforms``). The algebra behind every frame change of the paper (§II-A notation, the
pose parameters of §II-B.3, the transform chain of §II-C). See docs/architecture.md, "Frames and
units".
"""

from . import transforms as _transforms
from .transforms import (
                         RIGID_TOLERANCE,
                         as_points,
                         check_rigid,
                         check_rotation,
                         compose,
                         euler_from_matrix,
                         fit_sphere,
                         invert_transform,
                         make_transform,
                         matrix_from_euler,
                         matrix_from_quaternion,
                         matrix_from_rotvec,
                         params_from_transform,
                         quaternion_from_matrix,
                         random_rotation,
                         random_transform,
                         rotation_about_axis,
                         rotation_angle,
                         rotvec_from_matrix,
                         transform_from_params,
                         transform_points,
)

# every public name of the modules above, as each module's __all__ declares it
__all__ = list(dict.fromkeys([*_transforms.__all__]))
